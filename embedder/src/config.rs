//! Settings of the embedding model and its training.

use serde::{Deserialize, Serialize};

/// Embedding model and trainer settings (paper section 4.3 and appendix; public reference
/// code for the rest). The defaults are the gridworld's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmbeddingConfig {
    /// Width `m` of a state embedding `x`.
    pub state_dim: usize,
    /// Width `d` of an action embedding `e`.
    pub action_dim: usize,
    /// Adam learning rate of phi, g, T and f.
    pub lr: f64,
    /// Adam weight decay (L2) of phi, g, T and f.
    pub weight_decay: f32,
    /// Transitions per minibatch.
    pub batch_size: usize,
    /// Uniformly random transitions collected before pre-training. 3,000 gives the gridworld
    /// action embeddings no structure; 20,000 does.
    pub pretrain_transitions: usize,
    /// Passes over the pre-training transitions.
    pub pretrain_epochs: usize,
    /// Hidden width of the continuous-action decoder f.
    pub decoder_hidden: usize,
    /// Transitions the replay buffer keeps (oldest dropped first).
    pub replay_capacity: usize,
    /// Continuous updates: new transitions between two updates (0 turns them off).
    pub update_every: usize,
    /// Continuous updates: minibatch steps per update (each publishes a new version).
    pub update_steps: usize,
    /// Continuous updates: learning rate (usually below the pre-training one).
    pub update_lr: f64,
}

impl Default for EmbeddingConfig {
    fn default() -> Self {
        Self {
            state_dim: 8,
            action_dim: 2,
            lr: 0.01,
            weight_decay: 1e-4,
            batch_size: 512,
            pretrain_transitions: 20_000,
            pretrain_epochs: 100,
            decoder_hidden: 64,
            replay_capacity: 200_000,
            update_every: 0,
            update_steps: 50,
            update_lr: 0.001,
        }
    }
}

impl EmbeddingConfig {
    /// Checks the settings; the reason names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        if self.state_dim == 0 || self.action_dim == 0 {
            return Err("embedding.state_dim and embedding.action_dim must be positive".into());
        }
        if !(self.lr > 0.0 && self.lr.is_finite()) || !(self.update_lr > 0.0) {
            return Err("embedding.lr and embedding.update_lr must be positive".into());
        }
        if self.batch_size == 0 || self.pretrain_transitions == 0 || self.pretrain_epochs == 0 {
            return Err(
                "embedding.batch_size, pretrain_transitions and pretrain_epochs must be positive"
                    .into(),
            );
        }
        if self.replay_capacity < self.pretrain_transitions {
            return Err("embedding.replay_capacity must hold the pre-training transitions".into());
        }
        Ok(())
    }
}
