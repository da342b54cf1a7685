//! Where a Recommender's weights come from: a live run's learner (and embedder) followed over
//! gRPC, or a run directory's newest checkpoints, loaded at start and polled for newer ones.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use jsae_net::client::{self, PolicyEvent};
use jsae_net::security::Security;
use jsae_run_dir::{RunDir, Weights};
use jsae_wire::pb;
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot};

use crate::scoring::Recommender;

/// How often a followed run directory is checked for newer checkpoints.
pub(crate) const RUN_POLL: Duration = Duration::from_secs(3);

/// Where the weights come from.
#[derive(Debug, Clone, Default)]
pub struct WeightSources {
    /// Learner URL to follow.
    pub learner: Option<String>,
    /// Embedder URL to follow (JSAE).
    pub embedder: Option<String>,
    /// A finished run directory whose checkpoints are loaded at start.
    pub run: Option<PathBuf>,
}

/// Loads the newest checkpoints of a run directory (`DIR/checkpoints`) into `rec` where
/// they differ from the versions in use; returns whether anything changed.
pub fn load_run(rec: &Recommender, dir: &Path) -> anyhow::Result<bool> {
    let ckpt = RunDir::new(dir).checkpoints();
    let read = |path: &Path| {
        jsae_run_dir::read_weights(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    };
    let mut changed = false;
    if rec.config().algo.representation().needs_embedder() {
        let (version, path) = ckpt.newest(Weights::Embedding).ok_or_else(|| {
            anyhow::anyhow!("{}: no embedding checkpoint yet", ckpt.path().display())
        })?;
        if version > rec.embedding_version() && rec.refused_embedding() != Some(version) {
            let set = rec.set_embedding(EmbeddingSnapshot::from_bytes(version, read(&path)?));
            match set {
                Ok(()) => changed = true,
                // another catalogue's: said once (an error) and not read again; the policy
                // still loads
                Err(_) if rec.refused_embedding() == Some(version) => {}
                Err(e) => return Err(anyhow::Error::msg(e)),
            }
        }
    }
    let (version, path) = ckpt
        .newest(Weights::Policy)
        .ok_or_else(|| anyhow::anyhow!("{}: no policy checkpoint yet", ckpt.path().display()))?;
    if rec.policy_version() != Some(version) {
        rec.set_policy(&PolicySnapshot {
            version,
            bytes: read(&path)?,
        })
        .map_err(anyhow::Error::msg)?;
        changed = true;
    }
    Ok(changed)
}

/// Follows a run directory: loads its newest checkpoints now and whenever newer ones appear.
async fn follow_run(rec: Arc<Recommender>, dir: PathBuf) {
    let mut waiting_said = false;
    loop {
        let (r, d) = (rec.clone(), dir.clone());
        match tokio::task::spawn_blocking(move || load_run(&r, &d)).await {
            Ok(Ok(true)) => tracing::info!(
                "recommender: weights of {} (policy v{:?}, embedding v{})",
                dir.display(),
                rec.policy_version(),
                rec.embedding_version()
            ),
            Ok(Ok(false)) => {}
            Ok(Err(e)) if !waiting_said => {
                tracing::warn!("recommender: waiting for checkpoints: {e:#}");
                waiting_said = true;
            }
            Ok(Err(e)) => tracing::debug!("recommender: {e:#}"),
            Err(e) => tracing::warn!("recommender: {e}"),
        }
        tokio::time::sleep(RUN_POLL).await;
    }
}

/// Starts following `sources` for `rec` (a run directory is loaded once before this returns,
/// so a finished run answers from the first request; services are reached with `security`);
/// the tasks end when the set is dropped.
pub fn follow(
    rec: &Arc<Recommender>,
    sources: &WeightSources,
    security: &Security,
) -> tokio::task::JoinSet<()> {
    let mut tasks = tokio::task::JoinSet::new();
    if let Some(dir) = sources.run.clone() {
        // the first load before serving, so a finished run answers from the first request
        let _ = load_run(rec, &dir);
        tasks.spawn(follow_run(rec.clone(), dir));
    }
    if let Some(url) = sources.learner.clone() {
        let rec = rec.clone();
        let security = security.clone();
        tasks.spawn(async move {
            let followed =
                client::watch_policy(&security, &url, pb::WatchRequest::default(), |event| {
                    if let PolicyEvent::Snapshot(s) = &event {
                        match rec.set_policy(s) {
                            Ok(()) => tracing::debug!("recommender: policy v{}", s.version),
                            Err(e) => tracing::warn!("recommender: {e}"),
                        }
                    }
                    async { true }
                })
                .await;
            if let Err(e) = followed {
                tracing::error!("recommender: {e}; no new policy will arrive");
            }
        });
    }
    if let Some(url) = sources.embedder.clone() {
        let rec = rec.clone();
        let security = security.clone();
        tasks.spawn(async move {
            let followed = client::watch_embedding(&security, &url, |s| {
                // decoding a snapshot builds f's index (minutes at a million items): on a
                // blocking thread, so the runtime's workers go on answering meanwhile
                let rec = rec.clone();
                async move {
                    match tokio::task::spawn_blocking(move || rec.set_embedding(s)).await {
                        Ok(Ok(())) => {}
                        Ok(Err(e)) => tracing::warn!("recommender: {e}"),
                        Err(e) => tracing::error!("recommender: decoding an embedding: {e}"),
                    }
                    true
                }
            })
            .await;
            if let Err(e) = followed {
                tracing::error!("recommender: {e}; no new embedding will arrive");
            }
        });
    }
    tasks
}
