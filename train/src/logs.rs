//! The logged purchases a fresh learner's policy (`ppo.recommender.logged_prior`,
//! `ppo.recommender.logged_pretrain_epochs`) and a fresh embedding
//! (`embedding.recommender.logged_pretrain_epochs`) learn from before they play: the
//! recommender's sessions without the held-out ones, read as the environment reads them.
//! Neither the learner nor the embedder knows a data set; their callers (`jsae learner`,
//! `jsae embedder`, `jsae train --one-process`) pass these in.

use jsae_embedder::LoggedItems;
use jsae_envs::Env;
use jsae_envs::recsys::RecommenderEnv;
use jsae_learner::LoggedPurchases;
use jsae_settings::{EnvName, TrainConfig};
use jsae_wire::CatalogueTag;

/// The run's logged purchases where its settings ask for them; None where they do not.
///
/// # Errors
/// When the data cannot be read (the reason).
pub fn logged_purchases(config: &TrainConfig) -> Result<Option<LoggedPurchases>, String> {
    if !config.ppo.wants_logs() || config.env != EnvName::Recommender {
        return Ok(None);
    }
    let (env, states, next) = read(config)?;
    Ok(Some(LoggedPurchases {
        states,
        space: env.state_space().clone(),
        next,
    }))
}

/// The run's logged purchases for the embedder where its settings ask for them; None where
/// they do not.
///
/// # Errors
/// When the data cannot be read (the reason).
pub fn logged_items(config: &TrainConfig) -> Result<Option<LoggedItems>, String> {
    if config.embedding.recommender.logged_pretrain_epochs == 0
        || config.env != EnvName::Recommender
    {
        return Ok(None);
    }
    let (env, states, items) = read(config)?;
    let model = env.model();
    let catalogue = model.catalogue();
    Ok(Some(LoggedItems {
        states,
        items,
        catalogue: Some(CatalogueTag {
            items: catalogue.len() as u64,
            capacity: catalogue.capacity() as u64,
            prefix_hash: catalogue.prefix_hash(catalogue.len()).unwrap_or_default(),
        }),
    }))
}

fn read(config: &TrainConfig) -> Result<(RecommenderEnv, jsae_wire::StateBatch, Vec<u32>), String> {
    let env = RecommenderEnv::new(&config.environment)
        .map_err(|e| format!("reading the logged purchases: {e}"))?;
    let (states, next) = env.logged_steps();
    Ok((env, states, next))
}
