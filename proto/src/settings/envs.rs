//! Environment names and settings, and the state and action spaces they give (pure
//! arithmetic on the settings, so services that never step an environment agree with the
//! actors that do). The dynamics live in the actor library.

use serde::{Deserialize, Serialize};

use crate::{ActionSpace, StateSpace};

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
    /// MuJoCo HalfCheetah, as Gymnasium's HalfCheetah-v5 with default arguments.
    HalfCheetah,
    /// MuJoCo Ant, as Gymnasium's Ant-v5 with default arguments.
    Ant,
}

impl EnvName {
    /// The name as written on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Gridworld => "gridworld",
            Self::GridworldDiscrete => "gridworld-discrete",
            Self::Slotmachine => "slotmachine",
            Self::HalfCheetah => "half-cheetah",
            Self::Ant => "ant",
        }
    }

    /// Whether this is a MuJoCo environment.
    pub fn is_mujoco(self) -> bool {
        matches!(self, Self::HalfCheetah | Self::Ant)
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
    /// HalfCheetah and Ant.
    pub mujoco: MujocoConfig,
}

/// MuJoCo settings. Everything else is fixed to Gymnasium v5's defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MujocoConfig {
    /// Time limit in steps (Gymnasium's `max_episode_steps`: 1000).
    pub max_steps: u32,
}

impl Default for MujocoConfig {
    fn default() -> Self {
        Self { max_steps: 1000 }
    }
}

/// Gridworld settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GridworldConfig {
    /// Number of actuators `n`; there are `2^n` actions.
    pub actuators: u32,
    /// Time limit in steps.
    pub max_steps: u32,
    /// Bins per axis of the discrete variant.
    pub bins: u32,
    /// Sub-steps per step.
    pub substeps: u32,
    /// Length of a sub-step for a motion of norm 1.
    pub substep_len: f64,
    /// Reward of every step.
    pub step_reward: f64,
    /// Extra reward of a step that collides.
    pub collision_reward: f64,
    /// Extra reward of the step that reaches the goal.
    pub goal_reward: f64,
}

impl Default for GridworldConfig {
    fn default() -> Self {
        Self {
            actuators: 9,
            max_steps: 150,
            bins: 40,
            substeps: 4,
            substep_len: 0.045,
            step_reward: -0.01,
            collision_reward: -0.05,
            goal_reward: 1.0,
        }
    }
}

/// Slotmachine settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlotmachineConfig {
    /// Fractions of a turn per reel; there are `bins^4` actions.
    pub bins: u32,
    /// A value pays when it shows on at least this many reels.
    pub threshold: u32,
    /// Steps per episode.
    pub horizon: u32,
    /// The state as four categorical factors, one per reel (6 faces each; PPO sees 4
    /// concatenated one-hots of 6), instead of one one-hot over all 6^4 reel positions.
    pub factored: bool,
}

impl Default for SlotmachineConfig {
    fn default() -> Self {
        Self {
            bins: 8,
            threshold: 2,
            horizon: 20,
            factored: true,
        }
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
    if config.mujoco.max_steps == 0 {
        return Err("mujoco.max_steps must be positive".into());
    }
    Ok(())
}

impl EnvName {
    /// The state and action spaces of this environment under `config`.
    pub fn spaces(self, config: &EnvConfig) -> (StateSpace, ActionSpace) {
        match self {
            Self::Gridworld => (
                StateSpace::Real { dim: 2 },
                ActionSpace::Discrete {
                    n: 1 << config.gridworld.actuators,
                },
            ),
            Self::GridworldDiscrete => (
                StateSpace::discrete((config.gridworld.bins * config.gridworld.bins) as usize),
                ActionSpace::Discrete {
                    n: 1 << config.gridworld.actuators,
                },
            ),
            Self::Slotmachine => (
                if config.slotmachine.factored {
                    StateSpace::Categorical { sizes: vec![6; 4] }
                } else {
                    StateSpace::discrete(6usize.pow(4))
                },
                ActionSpace::Discrete {
                    n: (config.slotmachine.bins as usize).pow(4),
                },
            ),
            // qpos without x (8) + qvel (9)
            Self::HalfCheetah => (StateSpace::Real { dim: 17 }, unit_box(6)),
            // qpos without x, y (13) + qvel (14) + contact forces of 13 bodies (78)
            Self::Ant => (StateSpace::Real { dim: 105 }, unit_box(8)),
        }
    }
}

fn unit_box(dim: usize) -> ActionSpace {
    ActionSpace::Continuous {
        dim,
        low: vec![-1.0; dim],
        high: vec![1.0; dim],
    }
}
