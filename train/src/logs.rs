//! The logged purchases a fresh learner's policy (`ppo.recommender.logged_prior`,
//! `ppo.recommender.logged_pretrain_epochs`) and a fresh embedding
//! (`embedding.recommender.logged_pretrain_epochs`) learn from before they play: the
//! recommender's sessions without the held-out ones, read as the environment reads them.
//! Neither the learner nor the embedder knows a data set; their callers (`jsae learner`,
//! `jsae embedder`, `jsae train --one-process`) pass these in.

use jsae_embedder::LoggedItems;
use jsae_envs::recsys::{Catalogue, CatalogueHandle};
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
    let (_, states, next) = read(config)?;
    Ok(Some(LoggedPurchases {
        states,
        space: config.spaces().0,
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
    let (catalogue, states, items) = read(config)?;
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

/// The catalogue and its logged steps, read without the n-gram model (7 GB at its peak at a
/// million items; neither the learner nor the embedder steps the environment).
fn read(
    config: &TrainConfig,
) -> Result<(std::sync::Arc<Catalogue>, jsae_wire::StateBatch, Vec<u32>), String> {
    let r = &config.environment.recommender;
    let why = |e: jsae_envs::recsys::RecsysError| format!("reading the logged purchases: {e}");
    let handle = CatalogueHandle::load(r).map_err(why)?;
    let (states, next) = handle.logged_steps(r.history as usize).map_err(why)?;
    Ok((handle.current(), states, next))
}
