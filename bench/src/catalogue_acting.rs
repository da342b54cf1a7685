//! `train_env_steps_per_s` of `jsae bench --catalogue`: JSAE's acting at a catalogue's size,
//! as an actor steps in training: the recommender JSAE's environments (its default count,
//! one stepping thread) over the generated catalogue, each step phi, the policy and f through
//! the index. The n-gram model the environments sample from is built from the generated
//! sessions (at a million items about 80 s and 7 GB); the embedding is the category stand-in
//! and the policy freshly drawn, as in the Recommender's measurement (a trained model does
//! the same arithmetic).

use std::time::Instant;

use jsae_actor::worker::ActorWorker;
use jsae_envs::recsys::CatalogueHandle;
use jsae_envs::recsys::large_catalogue::LargeCatalogue;
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot};

use crate::catalogue_serving::{embedding_bytes, policy_bytes, settings};

/// Environment steps a second of one actor's stepping over `items` items, timed for at least
/// `seconds` after a first untimed rollout.
pub fn env_steps_per_s(items: u32, seconds: f64) -> anyhow::Result<f64> {
    let config = settings(items)?;
    let bytes = {
        let generated = LargeCatalogue::new(&config.environment.recommender.catalogue)
            .map_err(anyhow::Error::msg)?;
        let catalogue = CatalogueHandle::load(&config.environment.recommender)?.current();
        let tag = jsae_recommender::catalogue_tag(&catalogue);
        embedding_bytes(&config, &generated, &catalogue, 1, tag)?
    };
    let mut worker = ActorWorker::new(&config, 0, config.device)?;
    worker.set_embedding(&EmbeddingSnapshot::from_bytes(1, bytes))?;
    worker.set_policy(&PolicySnapshot {
        version: 1,
        bytes: policy_bytes(&config)?,
    })?;
    let rollout = config.rollout_len;
    worker.collect(rollout);
    let (started, from) = (Instant::now(), worker.env_steps());
    while started.elapsed().as_secs_f64() < seconds {
        worker.collect(rollout);
    }
    Ok((worker.env_steps() - from) as f64 / started.elapsed().as_secs_f64())
}
