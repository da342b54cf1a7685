//! The example of an environment brought in Rust (`--env corridor`;
//! docs/src/environments/bring-your-own.md walks through it): a corridor of `length` cells,
//! the agent starting in one of the first three, the goal the last cell. Each of the
//! `actions` actions moves one cell left, stays or moves one cell right (action `a` moves by
//! `a mod 3 - 1`), so many actions share one effect: the structure an action embedding is
//! meant to find. Every step costs `step_reward`; reaching the goal pays `goal_reward` and
//! terminates; after `max_steps` the episode is truncated.
//!
//! The crate depends on `jsae-env-api` (the [`Env`] trait) and `jsae-spaces` only, and is
//! registered in three places: `jsae-env-spec` (its name in `EnvName`, its settings in
//! `EnvConfig`, its spaces), and `jsae-envs` (`make_env`).

#![forbid(unsafe_code)]

use jsae_env_api::{ActionRef, Env, Step};
use jsae_spaces::{ActionSpace, StateBatch, StateSpace};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// This file, whose settings struct's doc comments `jsae config` prints beside the values.
pub const SOURCE: &str = include_str!("lib.rs");

/// The corridor's settings (`[environment.corridor]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorridorConfig {
    /// Cells; the last is the goal.
    pub length: u32,
    /// Actions; action `a` moves by `a mod 3 - 1` cells.
    pub actions: u32,
    /// Steps before the episode is truncated.
    pub max_steps: u32,
    /// Reward of every step.
    pub step_reward: f64,
    /// Extra reward of the step that reaches the goal.
    pub goal_reward: f64,
}

impl Default for CorridorConfig {
    fn default() -> Self {
        Self {
            length: 10,
            actions: 64,
            max_steps: 50,
            step_reward: -0.01,
            goal_reward: 1.0,
        }
    }
}

impl CorridorConfig {
    /// Checks the settings, with the reason when they are unusable.
    pub fn check(&self) -> Result<(), String> {
        if !(4..=1_000_000).contains(&self.length) {
            return Err(format!(
                "corridor.length must be in 4..=1000000, not {}",
                self.length
            ));
        }
        if !(3..=1_000_000).contains(&self.actions) || self.max_steps == 0 {
            return Err("corridor.actions must be in 3..=1000000 and max_steps positive".into());
        }
        if !(self.step_reward.is_finite() && self.goal_reward.is_finite()) {
            return Err("corridor rewards must be finite".into());
        }
        Ok(())
    }

    /// The state space (a cell, one-hot) and the action space.
    pub fn spaces(&self) -> (StateSpace, ActionSpace) {
        (
            StateSpace::discrete(self.length as usize),
            ActionSpace::Discrete {
                n: self.actions as usize,
            },
        )
    }
}

/// The corridor.
#[derive(Debug, Clone)]
pub struct Corridor {
    config: CorridorConfig,
    states: StateSpace,
    actions: ActionSpace,
    cell: u32,
    steps: u32,
}

impl Corridor {
    /// A corridor under `config` (checked by the run's validation first).
    pub fn new(config: CorridorConfig) -> Self {
        let (states, actions) = config.spaces();
        Self {
            config,
            states,
            actions,
            cell: 0,
            steps: 0,
        }
    }
}

impl Env for Corridor {
    fn state_space(&self) -> &StateSpace {
        &self.states
    }

    fn action_space(&self) -> &ActionSpace {
        &self.actions
    }

    fn has_success(&self) -> bool {
        true
    }

    fn reset(&mut self, rng: &mut ChaCha8Rng) {
        self.cell = rng.random_range(0..3);
        self.steps = 0;
    }

    fn step(&mut self, action: ActionRef<'_>) -> Step {
        let a = match action {
            ActionRef::Discrete(a) => a,
            // a continuous action is not this environment's: stay
            ActionRef::Continuous(_) => 1,
        };
        let last = self.config.length - 1;
        self.cell = match a % 3 {
            0 => self.cell.saturating_sub(1),
            1 => self.cell,
            _ => (self.cell + 1).min(last),
        };
        self.steps += 1;
        let reached = self.cell == last;
        Step {
            reward: self.config.step_reward
                + if reached {
                    self.config.goal_reward
                } else {
                    0.0
                },
            terminated: reached,
            truncated: !reached && self.steps >= self.config.max_steps,
            success: reached,
            lost: false,
        }
    }

    fn push_state(&self, out: &mut StateBatch) {
        if let StateBatch::Categorical { data, .. } = out {
            data.push(self.cell);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn walking_right_reaches_the_goal_and_terminates() {
        let mut env = Corridor::new(CorridorConfig::default());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        env.reset(&mut rng);
        let start = env.cell;
        let mut steps = 0;
        loop {
            // 5 mod 3 = 2: right
            let s = env.step(ActionRef::Discrete(5));
            steps += 1;
            if s.terminated {
                assert!(s.success && !s.truncated);
                assert!((s.reward - 0.99).abs() < 1e-12);
                break;
            }
            assert!((s.reward + 0.01).abs() < 1e-12);
        }
        assert_eq!(steps, 9 - start);
        let mut states = StateBatch::empty(env.state_space());
        env.push_state(&mut states);
        assert_eq!(
            states,
            StateBatch::Categorical {
                factors: 1,
                data: vec![9]
            }
        );
    }

    #[test]
    fn standing_still_is_truncated_at_the_time_limit() {
        let config = CorridorConfig {
            max_steps: 7,
            ..CorridorConfig::default()
        };
        let mut env = Corridor::new(config);
        env.reset(&mut ChaCha8Rng::seed_from_u64(1));
        let ends: Vec<Step> = (0..7).map(|_| env.step(ActionRef::Discrete(4))).collect();
        assert!(ends[..6].iter().all(|s| !s.truncated && !s.terminated));
        assert!(ends[6].truncated && !ends[6].terminated);
        assert!(
            CorridorConfig {
                length: 2,
                ..CorridorConfig::default()
            }
            .check()
            .is_err()
        );
    }
}
