//! Environments that step in Python worker processes (`--env gym:ID`): their Gymnasium id,
//! and the spaces their workers describe, mapped onto the run's state and action spaces.

use jsae_spaces::{ActionSpace, StateSpace};
use serde::{Deserialize, Serialize};

/// A Gymnasium space, as a worker describes it when it connects (`EnvHello`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GymSpace {
    /// `Discrete(n, start)`.
    Discrete {
        /// Values.
        n: u64,
        /// The first value.
        #[serde(default)]
        start: i64,
    },
    /// `MultiDiscrete(nvec)` (values from 0).
    MultiDiscrete {
        /// Values of each component.
        nvec: Vec<u64>,
    },
    /// `Box(low, high, shape)`, flattened row-major.
    Box {
        /// The shape.
        shape: Vec<u32>,
        /// The lower bound of each element (may be -inf).
        low: Vec<f32>,
        /// The upper bound of each element (may be inf).
        high: Vec<f32>,
    },
}

/// The most discrete actions a (multi-)discrete action space may have, and the most
/// categories of one observation factor.
pub const MAX_GYM_DISCRETE: u64 = 1 << 24;
/// The most elements a box may have (a rollout fragment of raw observations, 128 rows of
/// 16,384 float32, then stays within a message's 16 MiB).
pub const MAX_GYM_BOX: u64 = 1 << 14;

impl GymSpace {
    /// Elements of a box (the product of its shape).
    fn box_len(shape: &[u32]) -> u64 {
        shape.iter().map(|&d| u64::from(d)).product()
    }

    /// Checks the description, with the reason when the space cannot be used.
    pub fn check(&self, what: &str) -> Result<(), String> {
        match self {
            Self::Discrete { n, .. } if *n == 0 || *n > MAX_GYM_DISCRETE => Err(format!(
                "{what}: Discrete needs 1 to {MAX_GYM_DISCRETE} values, not {n}"
            )),
            Self::MultiDiscrete { nvec }
                if nvec.is_empty() || nvec.iter().any(|&n| n == 0 || n > MAX_GYM_DISCRETE) =>
            {
                Err(format!(
                    "{what}: MultiDiscrete needs components of 1 to {MAX_GYM_DISCRETE} values, \
                     not {nvec:?}"
                ))
            }
            Self::Box { shape, low, high } => {
                let len = Self::box_len(shape);
                if shape.is_empty() || len == 0 || len > MAX_GYM_BOX {
                    return Err(format!(
                        "{what}: Box needs 1 to {MAX_GYM_BOX} elements, not shape {shape:?}"
                    ));
                }
                if low.len() as u64 != len || high.len() as u64 != len {
                    return Err(format!(
                        "{what}: Box of shape {shape:?} has {len} elements, but {} lows and {} highs",
                        low.len(),
                        high.len()
                    ));
                }
                if low
                    .iter()
                    .zip(high)
                    .any(|(l, h)| l.is_nan() || h.is_nan() || l > h)
                {
                    return Err(format!("{what}: Box bounds with NaN or low > high"));
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// The run's state space for this observation space: a box is a real vector (its
    /// elements flattened), a (multi-)discrete space one categorical per component.
    pub fn state_space(&self) -> StateSpace {
        match self {
            Self::Discrete { n, .. } => StateSpace::discrete(*n as usize),
            Self::MultiDiscrete { nvec } => StateSpace::Categorical {
                sizes: nvec.iter().map(|&n| n as usize).collect(),
            },
            Self::Box { shape, .. } => StateSpace::Real {
                dim: Self::box_len(shape) as usize,
            },
        }
    }

    /// The run's action space for this action space: a box is continuous; a discrete space
    /// one action per value; a multi-discrete space one action per combination (mixed radix,
    /// the first component most significant). None when a multi-discrete space has more
    /// than [`MAX_GYM_DISCRETE`] combinations.
    pub fn action_space(&self) -> Option<ActionSpace> {
        match self {
            Self::Discrete { n, .. } => Some(ActionSpace::Discrete { n: *n as usize }),
            Self::MultiDiscrete { nvec } => nvec
                .iter()
                .try_fold(1u64, |acc, &n| acc.checked_mul(n))
                .filter(|&n| n <= MAX_GYM_DISCRETE)
                .map(|n| ActionSpace::Discrete { n: n as usize }),
            Self::Box { shape, low, high } => Some(ActionSpace::Continuous {
                dim: Self::box_len(shape) as usize,
                low: low.clone(),
                high: high.clone(),
            }),
        }
    }

    /// A short name for messages: `Box(17,)`, `Discrete(2)`.
    pub fn describe(&self) -> String {
        match self {
            Self::Discrete { n, start: 0 } => format!("Discrete({n})"),
            Self::Discrete { n, start } => format!("Discrete({n}, start={start})"),
            Self::MultiDiscrete { nvec } => format!("MultiDiscrete({nvec:?})"),
            Self::Box { shape, .. } => format!("Box{shape:?}"),
        }
    }
}

/// A remote environment: what `jsae train --env gym:ID` sets, and the spaces its workers
/// must describe (filled in from the environment itself when the run starts).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GymConfig {
    /// The Gymnasium id the workers make (`gymnasium.make(id)`), e.g. `CartPole-v1`.
    pub id: String,
    /// The observation space the workers must describe (empty: asked of the environment
    /// when the run starts, `python -m jsae.envs --describe`).
    pub observation: Option<GymSpace>,
    /// The action space the workers must describe (as `observation`).
    pub action: Option<GymSpace>,
    /// The time limit of an episode, in steps (Gymnasium's `max_episode_steps`; 0: none).
    pub max_steps: u32,
    /// Python worker processes each actor starts itself, its environments shared among
    /// them (0: none: workers started by hand connect to the actor's `--env-listen`).
    pub workers: u32,
}

impl Default for GymConfig {
    fn default() -> Self {
        Self {
            id: String::new(),
            observation: None,
            action: None,
            max_steps: 0,
            workers: 1,
        }
    }
}

impl GymConfig {
    /// The state and action spaces, once both are known and usable.
    pub fn spaces(&self) -> Result<(StateSpace, ActionSpace), String> {
        let (Some(observation), Some(action)) = (&self.observation, &self.action) else {
            return Err(format!(
                "the spaces of gym:{} are not known: `jsae train --env gym:{0}` asks the \
                 environment (python -m jsae.envs --describe --env {0}); a service started by \
                 hand needs the run's config.toml",
                self.id
            ));
        };
        observation.check("environment.gym.observation")?;
        action.check("environment.gym.action")?;
        let actions = action.action_space().ok_or_else(|| {
            format!(
                "environment.gym.action: {} has more than {MAX_GYM_DISCRETE} combinations",
                action.describe()
            )
        })?;
        Ok((observation.state_space(), actions))
    }

    /// Checks the settings, with the reason when they are unusable.
    pub fn check(&self) -> Result<(), String> {
        if self.id.is_empty() || self.id.len() > 256 || self.id.chars().any(char::is_control) {
            return Err(
                "environment.gym.id must name the Gymnasium environment (--env gym:ID)".into(),
            );
        }
        self.spaces().map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spaces_map_onto_the_runs() {
        let b = GymSpace::Box {
            shape: vec![2, 3],
            low: vec![-1.0; 6],
            high: vec![f32::INFINITY; 6],
        };
        assert_eq!(b.state_space(), StateSpace::Real { dim: 6 });
        assert!(b.check("obs").is_ok());
        let md = GymSpace::MultiDiscrete { nvec: vec![3, 4] };
        assert_eq!(md.action_space(), Some(ActionSpace::Discrete { n: 12 }));
        assert_eq!(
            md.state_space(),
            StateSpace::Categorical { sizes: vec![3, 4] }
        );
        let huge = GymSpace::MultiDiscrete {
            nvec: vec![1 << 20, 1 << 20],
        };
        assert_eq!(huge.action_space(), None);
    }

    #[test]
    fn bad_descriptions_are_refused_with_the_reason() {
        let short = GymSpace::Box {
            shape: vec![3],
            low: vec![0.0; 2],
            high: vec![1.0; 3],
        };
        assert!(short.check("obs").expect_err("refused").contains("2 lows"));
        assert!(GymSpace::Discrete { n: 0, start: 0 }.check("act").is_err());
        let config = GymConfig {
            id: "CartPole-v1".into(),
            ..GymConfig::default()
        };
        assert!(config.check().expect_err("refused").contains("not known"));
    }
}
