//! What an environment is to the rest of the system: the [`Env`] trait (Gymnasium's step
//! semantics: `terminated` and `truncated` apart), the [`Step`] it returns and the
//! [`ActionRef`] it takes. A crate that brings an environment depends on this one (and on
//! `jsae-spaces`) only; `jsae-env-spec` and `jsae-envs` register it
//! (docs/src/environments/bring-your-own.md).

#![forbid(unsafe_code)]

use jsae_spaces::{ActionBatch, ActionSpace, StateBatch, StateSpace};
use rand_chacha::ChaCha8Rng;

/// An action handed to an environment.
#[derive(Debug, Clone, Copy)]
pub enum ActionRef<'a> {
    /// A discrete action index.
    Discrete(u32),
    /// A continuous action (not clipped by the caller).
    Continuous(&'a [f32]),
}

impl<'a> ActionRef<'a> {
    /// Row `i` of `actions`.
    pub fn row(actions: &'a ActionBatch, i: usize) -> Self {
        match actions {
            ActionBatch::Discrete(a) => Self::Discrete(a[i]),
            ActionBatch::Continuous { dim, data } => {
                Self::Continuous(&data[i * dim..(i + 1) * dim])
            }
        }
    }
}

/// What one step produced.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Step {
    /// The reward.
    pub reward: f64,
    /// A terminal state was reached.
    pub terminated: bool,
    /// The time limit ended the episode (never together with `terminated`).
    pub truncated: bool,
    /// The step reached the goal, for environments with a success notion.
    pub success: bool,
    /// No step happened: the environment was lost (a remote worker died). Its episode ends
    /// truncated at the state before, with nothing to learn from this step; the next
    /// `reset` starts the environment's next episode wherever the pool can.
    pub lost: bool,
}

/// An environment. `reset` must be called before the first `step` and after every step
/// that terminated or truncated.
pub trait Env: Send {
    /// The state space.
    fn state_space(&self) -> &StateSpace;
    /// The action space.
    fn action_space(&self) -> &ActionSpace;
    /// Whether episodes have a success notion (reported as `eval_success_rate`).
    fn has_success(&self) -> bool;
    /// Starts a new episode; any randomness comes from `rng`.
    fn reset(&mut self, rng: &mut ChaCha8Rng);
    /// Executes one action.
    fn step(&mut self, action: ActionRef<'_>) -> Step;
    /// Appends the current state to `out`.
    fn push_state(&self, out: &mut StateBatch);
}
