//! The messages the components exchange.

use serde::{Deserialize, Serialize};

use crate::{ActionBatch, StateBatch};

/// Raw environment transitions, actor -> embedder. Row `i` of every field is one step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransitionBatch {
    /// Which actor sent it.
    pub actor_id: u64,
    /// States `s`.
    pub states: StateBatch,
    /// Actions `a` as executed (after `f`, before any clipping by the environment).
    pub actions: ActionBatch,
    /// Rewards `r`.
    pub rewards: Vec<f32>,
    /// Next states `s'` (the real next state, also at the end of an episode).
    pub next_states: StateBatch,
    /// Whether `s'` is terminal.
    pub terminated: Vec<bool>,
}

impl TransitionBatch {
    /// Number of transitions.
    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    /// Whether it holds no transition.
    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }
}

/// Statistics of one finished episode.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeStat {
    /// Undiscounted return.
    pub ret: f64,
    /// Number of steps.
    pub length: u32,
    /// Whether the goal was reached, for environments with a success notion.
    pub success: Option<bool>,
}

/// One environment's consecutive steps under one policy, actor -> learner.
///
/// Row `t` holds the policy input `x_t`, the sampled policy action (an embedding `e_t` for
/// JSAE, a raw action for PPO), its log-probability under the behaviour policy, and the
/// outcome of executing it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RolloutFragment {
    /// Which actor sent it.
    pub actor_id: u64,
    /// Which of the actor's environments it comes from.
    pub env_index: u32,
    /// Version of the policy that acted.
    pub policy_version: u64,
    /// Version of the embedding that computed `x` and decoded `e` (0 without embeddings).
    pub embedding_version: u64,
    /// The actor's env steps so far (all its environments, random ones included) when it
    /// sent this fragment: a claim the learner credits at most the fragment's length of
    /// (plus what is left of the run's random-play allowance), and ends the run on the sum
    /// of its credits.
    pub actor_env_steps: u64,
    /// Width of one policy input.
    pub x_dim: usize,
    /// Policy inputs, `[len, x_dim]`.
    pub x: Vec<f32>,
    /// Sampled policy actions: `Continuous` `[len, d]` for a Gaussian, `Discrete` for a
    /// categorical policy. Stored unclipped.
    pub actions: ActionBatch,
    /// Log-probability of each action under the behaviour policy, `[len]`.
    pub logp: Vec<f32>,
    /// Rewards, `[len]`.
    pub rewards: Vec<f32>,
    /// The step reached a terminal state (value 0 after it).
    pub terminated: Vec<bool>,
    /// The step hit the time limit (bootstrap with the value of its real next state).
    pub truncated: Vec<bool>,
    /// Policy inputs of the real next states of truncated steps, in step order,
    /// `[truncated count, x_dim]`.
    pub truncated_next_x: Vec<f32>,
    /// Policy input of the state after the last step, `[x_dim]`, to bootstrap the tail.
    pub last_next_x: Vec<f32>,
    /// Episodes that finished inside this fragment.
    pub episodes: Vec<EpisodeStat>,
    /// The actor process's random nonzero number, drawn when it started
    /// ([`crate::random_id`]): `actor_env_steps` counts within one incarnation, and a
    /// restarted actor reusing its id is another incarnation.
    pub actor_incarnation: u64,
    /// With the exploration bonus on (`exploration.bonus`): the key of every step's next
    /// state, one per reward, for the learner's visit counts over all actors; else empty.
    #[serde(default)]
    pub visit_keys: Vec<u64>,
}

impl RolloutFragment {
    /// Number of steps.
    pub fn len(&self) -> usize {
        self.rewards.len()
    }

    /// Whether it holds no step.
    pub fn is_empty(&self) -> bool {
        self.rewards.is_empty()
    }
}

/// A versioned copy of the embedding model (phi, g, T, f), embedder -> actors and learner.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EmbeddingSnapshot {
    /// Increases by one with every published snapshot, from 1.
    pub version: u64,
    /// The model's record bytes (burn `into_record().into_bytes()`).
    pub bytes: Vec<u8>,
    /// Model loss of the training round that produced it (JSAE: -log P(s'|s,a) or MSE; AE:
    /// the state reconstruction loss; RA: -log f(a | e(s, s')) or MSE).
    pub model_loss: f32,
    /// Decoder (f) loss of that round (0 for discrete actions).
    pub decoder_loss: f32,
    /// Structure of the action embeddings against the actions' true displacements (5-NN
    /// over all-pairs displacement distance; None where the environment has none).
    pub action_structure: Option<f32>,
}

impl EmbeddingSnapshot {
    /// A snapshot of stored weights (a checkpoint, a file): the training round's losses and
    /// structure are not stored with them.
    pub fn from_bytes(version: u64, bytes: Vec<u8>) -> Self {
        Self {
            version,
            bytes,
            model_loss: 0.0,
            decoder_loss: 0.0,
            action_structure: None,
        }
    }
}

/// A versioned copy of the policy (and whatever it needs at inference), learner -> actors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PolicySnapshot {
    /// Increases by one with every learner update, from 0 (the initial weights).
    pub version: u64,
    /// The policy's record bytes.
    pub bytes: Vec<u8>,
}

/// Evaluation episodes run by an actor at the end of a run, actor -> learner.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Policy version evaluated.
    pub policy_version: u64,
    /// Embedding version evaluated (0 without embeddings).
    pub embedding_version: u64,
    /// One entry per episode of the deterministic policy (mean action, then f).
    pub episodes: Vec<EpisodeStat>,
    /// One entry per episode with sampled actions, from the same start states (empty when
    /// not run).
    pub stochastic: Vec<EpisodeStat>,
}
