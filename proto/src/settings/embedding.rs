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
    /// Weight decay of phi, g, T and f.
    pub weight_decay: f32,
    /// Decoupled weight decay (AdamW). With Adam's L2 decay (`false`, the reference code's
    /// choice) a table row that gets no gradient, such as an unvisited state's phi(s), is
    /// pushed to 0 at a full learning-rate step per update, so every state random play never
    /// reached ends up with the same embedding.
    pub decoupled_weight_decay: bool,
    /// Transitions per minibatch.
    pub batch_size: usize,
    /// Uniformly random transitions collected before pre-training. 3,000 gives the gridworld
    /// action embeddings no structure; 20,000 does.
    pub pretrain_transitions: usize,
    /// Passes over the pre-training transitions.
    pub pretrain_epochs: usize,
    /// Hidden width of a tanh layer in T (0: T is one linear layer on `concat(x, e)`, as in the
    /// paper's gridworld; the slotmachine's next reel position is `position + advance mod 6`,
    /// which no linear function of the two embeddings can express).
    pub transition_hidden: usize,
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
    /// Real-valued states: phi sees them normalised by running mean and variance (part of
    /// the embedding's weights and snapshots), and T predicts normalised next states.
    pub normalize_states: bool,
}

impl Default for EmbeddingConfig {
    fn default() -> Self {
        Self {
            state_dim: 8,
            action_dim: 2,
            lr: 0.01,
            weight_decay: 1e-4,
            decoupled_weight_decay: true,
            batch_size: 512,
            pretrain_transitions: 20_000,
            pretrain_epochs: 30,
            transition_hidden: 0,
            decoder_hidden: 64,
            replay_capacity: 200_000,
            update_every: 20_480,
            update_steps: 50,
            update_lr: 0.003,
            normalize_states: false,
        }
    }
}

impl EmbeddingConfig {
    /// Checks the settings; the reason names the bad key.
    pub fn validate(&self) -> Result<(), String> {
        if self.state_dim == 0 || self.action_dim == 0 {
            return Err("embedding.state_dim and embedding.action_dim must be positive".into());
        }
        let positive = |v: f64| v > 0.0 && v.is_finite();
        if !positive(self.lr) || !positive(self.update_lr) {
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
