//! One learner update as a row of `metrics.csv` (and TensorBoard's scalars): the columns'
//! names and the values of an update in their order.

use jsae_run_dir::Scalar;

use crate::UpdateMetrics;

/// The scalars of one learner update, in the order of `metrics.csv`'s columns.
pub const UPDATE_COLUMNS: [&str; 24] = [
    "update",
    "env_steps",
    "wall_seconds",
    "return_mean",
    "success_rate",
    "episodes",
    "policy_lag_mean",
    "policy_lag_max",
    "dropped_lag",
    "dropped_embedding",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "clip_frac",
    "grad_norm",
    "explained_variance",
    "lr",
    "epochs",
    "log_std_mean",
    "policy_version",
    "embedding_version",
    "embedding_loss",
    "embedding_structure",
];

/// One learner update as named scalars (the names are [`UPDATE_COLUMNS`]);
/// `embedding_loss` and `embedding_structure` are the latest embedding snapshot's model loss
/// and action-embedding structure (`jsae_embedder::ActionStructure`; gridworlds only).
pub fn update_scalars(
    m: &UpdateMetrics,
    wall_seconds: f64,
    embedding: Option<&jsae_wire::EmbeddingSnapshot>,
) -> Vec<Scalar> {
    let n = |v: u64| Some(v as f64);
    let values = [
        n(m.update),
        n(m.env_steps),
        Some((wall_seconds * 1000.0).round() / 1000.0),
        m.return_mean,
        m.success_rate,
        n(m.episodes as u64),
        Some(m.policy_lag_mean),
        n(m.policy_lag_max),
        n(m.dropped_lag),
        n(m.dropped_embedding),
        Some(m.policy_loss),
        Some(m.value_loss),
        Some(m.entropy),
        Some(m.approx_kl),
        Some(m.clip_frac),
        Some(m.grad_norm),
        Some(m.explained_variance),
        Some(m.lr),
        n(m.epochs as u64),
        Some(m.log_std_mean),
        n(m.policy_version),
        n(m.embedding_version),
        embedding.map(|e| f64::from(e.model_loss)),
        embedding.and_then(|e| e.action_structure).map(f64::from),
    ];
    UPDATE_COLUMNS.into_iter().zip(values).collect()
}
