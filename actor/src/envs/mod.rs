//! Environments behind one trait, with Gymnasium's step semantics: `terminated` (a terminal
//! state was reached: value 0 after it) and `truncated` (the time limit cut the episode: the
//! next state still has a value) are separate.

mod geometry;
pub mod gridworld;
pub mod slotmachine;

use jsae_proto::{ActionSpace, StateBatch, StateSpace};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use gridworld::{Gridworld, GridworldConfig};
pub use slotmachine::{Slotmachine, SlotmachineConfig};

/// An action handed to an environment.
#[derive(Debug, Clone, Copy)]
pub enum ActionRef<'a> {
    /// A discrete action index.
    Discrete(u32),
    /// A continuous action (not clipped by the caller).
    Continuous(&'a [f32]),
}

/// What one step produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// The reward.
    pub reward: f64,
    /// A terminal state was reached.
    pub terminated: bool,
    /// The time limit ended the episode (never together with `terminated`).
    pub truncated: bool,
    /// The step reached the goal, for environments with a success notion.
    pub success: bool,
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

/// The environments `jsae train --env` accepts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum EnvName {
    /// Gridworld with the continuous (x, y) state.
    Gridworld,
    /// Gridworld with the coordinate binned into a 40x40 one-hot.
    GridworldDiscrete,
    /// Four reels, bins^4 actions.
    Slotmachine,
}

impl EnvName {
    /// The name as written on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Gridworld => "gridworld",
            Self::GridworldDiscrete => "gridworld-discrete",
            Self::Slotmachine => "slotmachine",
        }
    }
}

/// Settings of every environment; `jsae train` uses the part its `--env` names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct EnvConfig {
    /// Both gridworld variants.
    pub gridworld: GridworldConfig,
    /// The slotmachine.
    pub slotmachine: SlotmachineConfig,
}

/// Builds the named environment.
pub fn make_env(name: EnvName, config: &EnvConfig) -> Box<dyn Env> {
    match name {
        EnvName::Gridworld => Box::new(Gridworld::new(config.gridworld.clone(), false)),
        EnvName::GridworldDiscrete => Box::new(Gridworld::new(config.gridworld.clone(), true)),
        EnvName::Slotmachine => Box::new(Slotmachine::new(config.slotmachine.clone())),
    }
}

/// Checks settings that would make an environment meaningless.
pub fn validate_env_config(config: &EnvConfig) -> Result<(), String> {
    let g = &config.gridworld;
    if !(1..=16).contains(&g.actuators) {
        return Err(format!(
            "gridworld.actuators must be in 1..=16, got {}",
            g.actuators
        ));
    }
    if g.max_steps == 0 || g.bins == 0 {
        return Err("gridworld.max_steps and gridworld.bins must be positive".into());
    }
    let s = &config.slotmachine;
    if !(1..=16).contains(&s.bins) {
        return Err(format!(
            "slotmachine.bins must be in 1..=16, got {}",
            s.bins
        ));
    }
    if !(1..=4).contains(&s.threshold) || s.horizon == 0 {
        return Err("slotmachine.threshold must be in 1..=4 and horizon positive".into());
    }
    Ok(())
}
