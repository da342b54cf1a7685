//! The weights an agent acts with, swapped in whole as snapshots arrive. The actor's rollout
//! worker and the Recommender both act through [`Weights`], so both apply snapshots by the
//! same rules:
//! - a policy snapshot of any version other than the one in use replaces it (an older one
//!   too: that is a learner restarted without a checkpoint, whose versions are valid now);
//! - an embedding snapshot replaces the one in use only when it is newer.

use crate::embedding::Embedding;
use crate::policy::{Policy, PolicyPrior, policy_shape};
use crate::prior::CountPrior;
use burn::tensor::Device;
use jsae_nn::RecordError;
use jsae_settings::TrainConfig;
use jsae_wire::{ActionSpace, EmbeddingSnapshot, PolicySnapshot, StateSpace};
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
    /// The count prior its logits add (`ppo.recommender.logged_prior`), read with its bytes.
    prior: PolicyPrior,
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
            prior: PolicyPrior::new(&config.ppo),
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

    /// The count prior the policy's logits add, to pass to [`Policy::act`] (None unless
    /// `ppo.recommender.logged_prior`).
    pub fn prior(&self) -> Option<&CountPrior> {
        self.prior.get()
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
        let (mut policy, mut prior) = (self.policy.clone(), self.prior.clone());
        prior
            .decode(&mut policy, &snapshot.bytes)
            .map_err(|source| SwapError {
                kind: "policy",
                version: snapshot.version,
                source,
            })?;
        (self.policy, self.prior) = (policy, prior);
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
        self.embedding = Some(self.decode_embedding(snapshot)?);
        Ok(())
    }

    /// Installs an embedding decoded by [`Self::decode_embedding`] if it is newer than the
    /// one in use; returns whether it did.
    pub fn install_embedding(&mut self, embedding: Embedding) -> bool {
        if embedding.version() <= self.embedding_version() {
            return false;
        }
        self.embedding = Some(embedding);
        true
    }

    /// [`Self::decode_embedding`] of a snapshot the caller gives up (its bytes are not
    /// copied, and are dropped before f's index is built), an approximate index built by
    /// `index_threads` threads (0: every core).
    pub fn decode_owned_embedding(
        &self,
        snapshot: EmbeddingSnapshot,
        index_threads: usize,
    ) -> Result<Embedding, SwapError> {
        let version = snapshot.version;
        Embedding::from_owned_snapshot(
            &self.config.embedding,
            self.config.algo.representation(),
            &self.states,
            &self.actions,
            (snapshot, index_threads),
            &self.device,
        )
        .map_err(|source| SwapError {
            kind: "embedding",
            version,
            source,
        })
    }

    /// Decodes `snapshot` for these weights' settings and spaces without installing it (f's
    /// index is built here: minutes at a million actions).
    pub fn decode_embedding(&self, snapshot: &EmbeddingSnapshot) -> Result<Embedding, SwapError> {
        Embedding::from_snapshot(
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
        })
    }
}
