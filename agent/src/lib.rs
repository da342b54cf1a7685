//! The acting side of a trained agent: the policy and the embedding in use, swapped in whole
//! as snapshots arrive. The actor's rollout worker and the Recommender both act through
//! [`Weights`], so both apply snapshots by the same rules:
//! - a policy snapshot of any version other than the one in use replaces it (an older one
//!   too: that is a learner restarted without a checkpoint, whose versions are valid now);
//! - an embedding snapshot replaces the one in use only when it is newer.

#![forbid(unsafe_code)]

pub mod greedy;

use burn::tensor::Device;
use jsae_embedder::Embedding;
use jsae_learner::{Policy, policy_shape};
use jsae_nn::RecordError;
use jsae_proto::settings::TrainConfig;
use jsae_proto::{ActionBatch, ActionSpace, EmbeddingSnapshot, PolicySnapshot, StateSpace};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A snapshot whose bytes do not fit the model.
#[derive(Debug, thiserror::Error)]
#[error("{kind} version {version}: {source}")]
pub struct SwapError {
    /// `policy` or `embedding`.
    pub kind: &'static str,
    /// The snapshot's version.
    pub version: u64,
    /// The cause.
    pub source: RecordError,
}

/// The weights an agent acts with.
#[derive(Debug, Clone)]
pub struct Weights {
    config: TrainConfig,
    states: StateSpace,
    actions: ActionSpace,
    device: Device,
    /// The policy in use; the untrained template (its shape) before the first snapshot.
    policy: Policy,
    policy_version: Option<u64>,
    embedding: Option<Embedding>,
}

impl Weights {
    /// No weights yet, for a run's settings and spaces, on `device`.
    pub fn new(
        config: &TrainConfig,
        states: &StateSpace,
        actions: &ActionSpace,
        device: &Device,
    ) -> Self {
        let (input, head) = policy_shape(config, states, actions);
        let policy = Policy::new(
            &config.ppo,
            input,
            head,
            &mut ChaCha8Rng::seed_from_u64(0),
            device,
        );
        Self {
            config: config.clone(),
            states: states.clone(),
            actions: actions.clone(),
            device: device.clone(),
            policy,
            policy_version: None,
            embedding: None,
        }
    }

    /// The policy in use and its version (None before the first policy snapshot).
    pub fn policy(&self) -> Option<(u64, &Policy)> {
        self.policy_version.map(|v| (v, &self.policy))
    }

    /// The policy to act with: the one in use, or the untrained template before the first
    /// snapshot (its input width and head are the run's).
    pub fn acting_policy(&self) -> &Policy {
        &self.policy
    }

    /// The policy version in use.
    pub fn policy_version(&self) -> Option<u64> {
        self.policy_version
    }

    /// The embedding in use.
    pub fn embedding(&self) -> Option<&Embedding> {
        self.embedding.as_ref()
    }

    /// The embedding in use, to decode with.
    pub fn embedding_mut(&mut self) -> Option<&mut Embedding> {
        self.embedding.as_mut()
    }

    /// Overwrites the first `x.len() / input` rows of `points` (sampled action embeddings)
    /// and `logp` with the deterministic policy's choices for the policy inputs `x`
    /// ([`greedy::greedy_points`]); nothing without an embedding.
    pub fn act_greedily(&mut self, x: &[f32], points: &mut [f32], logp: &mut [f32]) {
        let Some(embedding) = self.embedding.as_mut() else {
            return;
        };
        let mut means = ActionBatch::empty(&self.policy.head().action_space());
        let mut unused = Vec::new();
        // the mean draws nothing from the generator
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        self.policy.act(x, true, &mut rng, &mut means, &mut unused);
        if let ActionBatch::Continuous { data, .. } = &means {
            greedy::greedy_points(embedding, &self.policy, data, points, logp);
        }
    }

    /// The embedding version in use (0: none yet).
    pub fn embedding_version(&self) -> u64 {
        self.embedding.as_ref().map_or(0, Embedding::version)
    }

    /// Whether everything the algorithm acts through has arrived (the policy, and the
    /// embedding where the representation needs one).
    pub fn ready(&self) -> bool {
        self.policy_version.is_some()
            && (!self.config.algo.representation().needs_embedder() || self.embedding.is_some())
    }

    /// Swaps in a policy snapshot of any version other than the one in use; returns whether
    /// it did.
    pub fn set_policy(&mut self, snapshot: &PolicySnapshot) -> Result<bool, SwapError> {
        if self.policy_version == Some(snapshot.version) {
            return Ok(false);
        }
        let mut policy = self.policy.clone();
        policy
            .load_bytes(&snapshot.bytes)
            .map_err(|source| SwapError {
                kind: "policy",
                version: snapshot.version,
                source,
            })?;
        self.policy = policy;
        self.policy_version = Some(snapshot.version);
        Ok(true)
    }

    /// Swaps in a newer embedding snapshot; returns whether it did.
    pub fn set_embedding(&mut self, snapshot: &EmbeddingSnapshot) -> Result<bool, SwapError> {
        if snapshot.version <= self.embedding_version() {
            return Ok(false);
        }
        self.load_embedding(snapshot)?;
        Ok(true)
    }

    /// Installs `snapshot` whatever its version, an older one too (the end-of-run evaluation
    /// goes back to the embedding the final policy was trained on).
    pub fn load_embedding(&mut self, snapshot: &EmbeddingSnapshot) -> Result<(), SwapError> {
        let embedding = Embedding::from_snapshot(
            &self.config.embedding,
            self.config.algo.representation(),
            &self.states,
            &self.actions,
            snapshot,
            &self.device,
        )
        .map_err(|source| SwapError {
            kind: "embedding",
            version: snapshot.version,
            source,
        })?;
        self.embedding = Some(embedding);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_embedder::EmbeddingModel;
    use jsae_nn::{BurnDevice, DeviceKind};
    use jsae_proto::settings::{Algo, EnvName};
    use rand::Rng;

    /// The deterministic policy's steps in training record, in place of their samples, a point
    /// that decodes to f of the mean (the action's own embedding) with that point's
    /// log-probability; the other rows keep their samples.
    #[test]
    fn greedy_steps_record_the_embedding_of_the_decoded_mean() {
        let config = TrainConfig::defaults(EnvName::GridworldDiscrete, Algo::Jsae);
        let (states, actions) = config.spaces();
        let device = DeviceKind::Flex.device();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let model = EmbeddingModel::new(
            &config.embedding,
            config.algo.representation(),
            &states,
            &actions,
            &mut rng,
            &device,
        );
        let snapshot = EmbeddingSnapshot {
            version: 1,
            bytes: model.to_bytes().expect("serialises"),
            model_loss: 0.0,
            decoder_loss: 0.0,
            action_structure: None,
        };
        let mut weights = Weights::new(&config, &states, &actions, &device);
        weights.load_embedding(&snapshot).expect("loads");
        let input = weights.acting_policy().input_dim();
        let d = config.embedding.action_dim;
        let x: Vec<f32> = (0..4 * input)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let mut points = vec![0.25; 4 * d];
        let mut logp = vec![7.0; 4];
        weights.act_greedily(&x[..2 * input], &mut points, &mut logp);
        let policy = weights.acting_policy().clone();
        let mut means = ActionBatch::empty(&policy.head().action_space());
        policy.act(&x[..2 * input], true, &mut rng, &mut means, &mut Vec::new());
        let ActionBatch::Continuous { data: means, .. } = means else {
            panic!("a Gaussian over E");
        };
        let embedding = weights.embedding_mut().expect("loaded");
        let decode = |e: &mut Embedding, points: &[f32]| {
            let mut out = ActionBatch::Discrete(Vec::new());
            e.decode(points, &mut out);
            out
        };
        assert_eq!(
            decode(embedding, &points[..2 * d]),
            decode(embedding, &means)
        );
        for row in 0..2 {
            let (mean, point) = (&means[row * d..][..d], &points[row * d..][..d]);
            assert_eq!(logp[row], policy.gaussian_log_prob(mean, point));
            assert!(logp[row].is_finite() && logp[row] != 7.0);
        }
        assert_eq!(points[2 * d..].to_vec(), vec![0.25; 2 * d]);
        assert_eq!(&logp[2..], &[7.0, 7.0]);
    }
}
