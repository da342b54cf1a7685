//! The logged purchases a fresh learner's policy learns from before it plays
//! (`ppo.recommender.logged_prior`, `ppo.recommender.logged_pretrain_epochs`): the recommender's sessions without the
//! held-out ones, read as the environment reads them. The learner knows no data set; its
//! callers (`jsae learner`, `jsae train --one-process`) pass this in.

use jsae_envs::Env;
use jsae_envs::recsys::RecommenderEnv;
use jsae_learner::LoggedPurchases;
use jsae_settings::{EnvName, TrainConfig};

/// The run's logged purchases where its settings ask for them; None where they do not.
///
/// # Errors
/// When the data cannot be read (the reason).
pub fn logged_purchases(config: &TrainConfig) -> Result<Option<LoggedPurchases>, String> {
    if !config.ppo.wants_logs() || config.env != EnvName::Recommender {
        return Ok(None);
    }
    let env = RecommenderEnv::new(&config.environment)
        .map_err(|e| format!("reading the logged purchases: {e}"))?;
    let (states, next) = env.logged_steps();
    Ok(Some(LoggedPurchases {
        states,
        space: env.state_space().clone(),
        next,
    }))
}
