//! Input checks every receiver runs before accepting a message.

use crate::{
    ActionBatch, ActionSpace, EpisodeStat, EvalReport, RolloutFragment, StateBatch, StateSpace,
    TransitionBatch,
};

/// Why a message was refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ValidationError {
    /// A field's length does not match the others or the declared dimensions.
    #[error("{field}: expected {expected} values, got {got}")]
    Length {
        /// The field.
        field: &'static str,
        /// The length it should have.
        expected: usize,
        /// The length it has.
        got: usize,
    },
    /// A value is NaN or infinite.
    #[error("{field}: value {index} is not finite")]
    NotFinite {
        /// The field.
        field: &'static str,
        /// Index of the first bad value.
        index: usize,
    },
    /// A category or action index is out of range.
    #[error("{field}: index {value} out of range 0..{limit}")]
    OutOfRange {
        /// The field.
        field: &'static str,
        /// The value.
        value: u32,
        /// The exclusive upper bound.
        limit: usize,
    },
    /// A required part of a message is absent.
    #[error("{field}: missing")]
    Missing {
        /// The field.
        field: &'static str,
    },
    /// A message or field is larger than allowed.
    #[error("{field}: {got} bytes, at most {limit}")]
    TooLarge {
        /// The field.
        field: &'static str,
        /// The limit.
        limit: usize,
        /// The size it has.
        got: usize,
    },
    /// Chunks arrived out of order or do not add up.
    #[error("{field}: chunks out of sequence")]
    Sequence {
        /// The field.
        field: &'static str,
    },
    /// The kind of a state or action batch does not match the space.
    #[error("{field}: kind does not match the environment's space")]
    Kind {
        /// The field.
        field: &'static str,
    },
    /// A message that must carry at least one value carries none.
    #[error("{field}: empty (at least one step)")]
    Empty {
        /// The field.
        field: &'static str,
    },
    /// A finite value outside the range the receiver accepts.
    #[error("{field}: value {index} is {value}, outside [{lo}, {hi}]")]
    Range {
        /// The field.
        field: &'static str,
        /// Index of the first such value.
        index: usize,
        /// The value.
        value: f32,
        /// The lowest accepted.
        lo: f32,
        /// The highest accepted.
        hi: f32,
    },
    /// An episode's statistics no real run can produce.
    #[error(
        "episodes: episode {index} has length {length} and return {ret}: at least one step, \
         and a return its steps' bounded rewards can make"
    )]
    Episode {
        /// Index of the episode in the message.
        index: usize,
        /// Its return.
        ret: f64,
        /// Its length.
        length: u32,
    },
    /// A finite value beyond the bound the receiver accepts.
    #[error("{field}: value {index} is {value}, beyond +-{limit}")]
    Bound {
        /// The field.
        field: &'static str,
        /// Index of the first such value.
        index: usize,
        /// The value.
        value: f32,
        /// The largest magnitude accepted.
        limit: f32,
    },
}

fn check_len(field: &'static str, expected: usize, got: usize) -> Result<(), ValidationError> {
    if expected == got {
        Ok(())
    } else {
        Err(ValidationError::Length {
            field,
            expected,
            got,
        })
    }
}

fn check_finite(field: &'static str, values: &[f32]) -> Result<(), ValidationError> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(index) => Err(ValidationError::NotFinite { field, index }),
    }
}

fn check_states(
    field: &'static str,
    batch: &StateBatch,
    space: &StateSpace,
    rows: usize,
) -> Result<(), ValidationError> {
    match (batch, space) {
        (StateBatch::Categorical { factors, data }, StateSpace::Categorical { sizes }) => {
            check_len(field, sizes.len(), *factors)?;
            check_len(field, rows * sizes.len(), data.len())?;
            for row in data.chunks_exact(sizes.len().max(1)) {
                for (&v, &limit) in row.iter().zip(sizes) {
                    if v as usize >= limit {
                        return Err(ValidationError::OutOfRange {
                            field,
                            value: v,
                            limit,
                        });
                    }
                }
            }
            Ok(())
        }
        (StateBatch::Real { dim, data }, StateSpace::Real { dim: want }) => {
            check_len(field, *want, *dim)?;
            check_len(field, rows * want, data.len())?;
            check_finite(field, data)?;
            check_bound(field, data, MAX_ABS_POLICY_INPUT)
        }
        _ => Err(ValidationError::Kind { field }),
    }
}

fn check_actions(
    field: &'static str,
    batch: &ActionBatch,
    space: &ActionSpace,
    rows: usize,
) -> Result<(), ValidationError> {
    match (batch, space) {
        (ActionBatch::Discrete(v), ActionSpace::Discrete { n }) => {
            check_len(field, rows, v.len())?;
            match v.iter().find(|&&a| a as usize >= *n) {
                Some(&value) => Err(ValidationError::OutOfRange {
                    field,
                    value,
                    limit: *n,
                }),
                None => Ok(()),
            }
        }
        (ActionBatch::Continuous { dim, data }, ActionSpace::Continuous { dim: want, .. }) => {
            check_len(field, *want, *dim)?;
            check_len(field, rows * want, data.len())?;
            check_finite(field, data)
        }
        _ => Err(ValidationError::Kind { field }),
    }
}

/// Checks a batch of states alone (shape, ranges, finite values) against `space`.
pub fn validate_states(batch: &StateBatch, space: &StateSpace) -> Result<(), ValidationError> {
    check_states("states", batch, space, batch.len())
}

impl TransitionBatch {
    /// Checks dimensions, ranges and finiteness against the environment's spaces, real
    /// states within [`MAX_ABS_POLICY_INPUT`] and rewards within `max_abs_reward`
    /// (`ppo.max_abs_reward`, as the learner's).
    pub fn validate(
        &self,
        states: &StateSpace,
        actions: &ActionSpace,
        max_abs_reward: f32,
    ) -> Result<(), ValidationError> {
        let n = self.rewards.len();
        check_states("states", &self.states, states, n)?;
        check_states("next_states", &self.next_states, states, n)?;
        check_actions("actions", &self.actions, actions, n)?;
        check_len("terminated", n, self.terminated.len())?;
        check_finite("rewards", &self.rewards)?;
        check_bound("rewards", &self.rewards, max_abs_reward)
    }
}

fn check_bound(field: &'static str, values: &[f32], limit: f32) -> Result<(), ValidationError> {
    match values.iter().position(|v| v.abs() > limit) {
        None => Ok(()),
        Some(index) => Err(ValidationError::Bound {
            field,
            index,
            value: values[index],
            limit,
        }),
    }
}

/// Largest magnitude of a policy input a fragment may carry (`x`, `truncated_next_x`,
/// `last_next_x`). Far beyond any environment's observation or embedding, yet its square
/// (in the observation statistics) stays finite in `f32`.
pub const MAX_ABS_POLICY_INPUT: f32 = 1e6;

/// What a receiver accepts of a rollout fragment: the policy's input width and action
/// space, and the range of every value a real actor can send.
#[derive(Debug, Clone, PartialEq)]
pub struct FragmentBounds {
    /// Width of one policy input.
    pub x_dim: usize,
    /// The space the policy samples in.
    pub actions: ActionSpace,
    /// `ppo.max_abs_reward`: the largest reward magnitude.
    pub max_abs_reward: f32,
    /// The behaviour log-probabilities the policy can give, `(lowest, highest)` (the
    /// learner's `policy::behaviour_logp_range`).
    pub logp: (f32, f32),
    /// The most steps an episode lasts (the environment's time limit; `u32::MAX` where
    /// unknown).
    pub max_episode_steps: u32,
}

fn check_range(
    field: &'static str,
    values: &[f32],
    (lo, hi): (f32, f32),
) -> Result<(), ValidationError> {
    match values.iter().position(|v| !(lo..=hi).contains(v)) {
        None => Ok(()),
        Some(index) => Err(ValidationError::Range {
            field,
            index,
            value: values[index],
            lo,
            hi,
        }),
    }
}

impl RolloutFragment {
    /// Checks dimensions, finiteness and ranges against `bounds`: at least one step; inputs
    /// within [`MAX_ABS_POLICY_INPUT`]; log-probabilities within what the policy can give;
    /// rewards within `max_abs_reward`; no more episodes than steps that end one, each at
    /// least one step long with a return its length of bounded rewards can make.
    pub fn validate(&self, bounds: &FragmentBounds) -> Result<(), ValidationError> {
        let (x_dim, n) = (bounds.x_dim, self.rewards.len());
        if n == 0 {
            return Err(ValidationError::Empty { field: "rewards" });
        }
        check_len("x_dim", x_dim, self.x_dim)?;
        check_len("x", n * x_dim, self.x.len())?;
        check_finite("x", &self.x)?;
        check_bound("x", &self.x, MAX_ABS_POLICY_INPUT)?;
        check_actions("actions", &self.actions, &bounds.actions, n)?;
        check_len("logp", n, self.logp.len())?;
        check_finite("logp", &self.logp)?;
        check_range("logp", &self.logp, bounds.logp)?;
        check_finite("rewards", &self.rewards)?;
        check_bound("rewards", &self.rewards, bounds.max_abs_reward)?;
        check_len("terminated", n, self.terminated.len())?;
        check_len("truncated", n, self.truncated.len())?;
        let cuts = self.truncated.iter().filter(|&&t| t).count();
        check_len(
            "truncated_next_x",
            cuts * x_dim,
            self.truncated_next_x.len(),
        )?;
        check_finite("truncated_next_x", &self.truncated_next_x)?;
        check_bound(
            "truncated_next_x",
            &self.truncated_next_x,
            MAX_ABS_POLICY_INPUT,
        )?;
        check_len("last_next_x", x_dim, self.last_next_x.len())?;
        check_finite("last_next_x", &self.last_next_x)?;
        check_bound("last_next_x", &self.last_next_x, MAX_ABS_POLICY_INPUT)?;
        if !self.visit_keys.is_empty() {
            check_len("visit_keys", n, self.visit_keys.len())?;
        }
        self.check_episodes(bounds)
    }

    /// At most one episode per step that ends one, each as [`check_episodes`] wants it.
    fn check_episodes(&self, bounds: &FragmentBounds) -> Result<(), ValidationError> {
        let ends = (self.terminated.iter().zip(&self.truncated))
            .filter(|&(&t, &c)| t || c)
            .count();
        if self.episodes.len() > ends {
            return Err(ValidationError::Length {
                field: "episodes (at most one per step that ends one)",
                expected: ends,
                got: self.episodes.len(),
            });
        }
        check_episodes(&self.episodes, bounds)
    }
}

/// Each episode at least a step long and at most `max_episode_steps`, its return within
/// what its length of rewards within `max_abs_reward` can make (1% slack: actors sum the
/// rewards before they are rounded to `f32`).
pub fn check_episodes(
    episodes: &[EpisodeStat],
    bounds: &FragmentBounds,
) -> Result<(), ValidationError> {
    for (index, e) in episodes.iter().enumerate() {
        let most = f64::from(bounds.max_abs_reward) * f64::from(e.length) * 1.01;
        let length_ok = (1..=bounds.max_episode_steps).contains(&e.length);
        if !length_ok || !e.ret.is_finite() || e.ret.abs() > most {
            return Err(ValidationError::Episode {
                index,
                ret: e.ret,
                length: e.length,
            });
        }
    }
    Ok(())
}

impl EvalReport {
    /// Checks a report against the request it answers (`asked` episodes) and `bounds`: as
    /// many deterministic episodes as asked, as many sampled ones or none, each episode
    /// within [`check_episodes`].
    pub fn check(&self, asked: u32, bounds: &FragmentBounds) -> Result<(), ValidationError> {
        let asked = asked as usize;
        check_len("episodes", asked, self.episodes.len())?;
        if !self.stochastic.is_empty() {
            check_len("stochastic_episodes", asked, self.stochastic.len())?;
        }
        check_episodes(&self.episodes, bounds)?;
        check_episodes(&self.stochastic, bounds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fragment() -> RolloutFragment {
        RolloutFragment {
            actor_id: 0,
            env_index: 0,
            policy_version: 1,
            embedding_version: 1,
            actor_env_steps: 2,
            x_dim: 2,
            x: vec![0.0; 4],
            actions: ActionBatch::Continuous {
                dim: 1,
                data: vec![0.5, -0.5],
            },
            logp: vec![-1.0, -1.0],
            rewards: vec![0.0, 1.0],
            terminated: vec![false, false],
            truncated: vec![false, true],
            truncated_next_x: vec![0.1, 0.2],
            last_next_x: vec![0.0, 0.0],
            episodes: vec![],
            actor_incarnation: 1,
            visit_keys: Vec::new(),
        }
    }

    fn space() -> ActionSpace {
        ActionSpace::Continuous {
            dim: 1,
            low: vec![-1.0],
            high: vec![1.0],
        }
    }

    fn bounds(x_dim: usize) -> FragmentBounds {
        FragmentBounds {
            x_dim,
            actions: space(),
            max_abs_reward: 1e6,
            logp: (-100.0, 5.0),
            max_episode_steps: 1000,
        }
    }

    #[test]
    fn a_consistent_fragment_passes() {
        assert_eq!(fragment().validate(&bounds(2)), Ok(()));
    }

    #[test]
    fn wrong_dimensions_nan_and_missing_bootstrap_are_refused() {
        let mut f = fragment();
        f.x.pop();
        assert!(matches!(
            f.validate(&bounds(2)),
            Err(ValidationError::Length { field: "x", .. })
        ));
        let mut f = fragment();
        f.rewards[0] = f32::NAN;
        assert!(matches!(
            f.validate(&bounds(2)),
            Err(ValidationError::NotFinite { .. })
        ));
        let mut f = fragment();
        f.truncated_next_x.clear();
        assert!(f.validate(&bounds(2)).is_err());
        assert!(fragment().validate(&bounds(3)).is_err());
        let mut f = fragment();
        f.visit_keys = vec![7];
        assert!(matches!(
            f.validate(&bounds(2)),
            Err(ValidationError::Length {
                field: "visit_keys",
                ..
            })
        ));
        f.visit_keys = vec![7, 8];
        assert_eq!(f.validate(&bounds(2)), Ok(()), "one key a step");
    }

    #[test]
    fn finite_rewards_beyond_the_bound_are_refused() {
        let mut f = fragment();
        f.rewards[1] = 3e38;
        assert_eq!(
            f.validate(&bounds(2)),
            Err(ValidationError::Bound {
                field: "rewards",
                index: 1,
                value: 3e38,
                limit: 1e6
            })
        );
        f.rewards[1] = -1e6;
        assert_eq!(f.validate(&bounds(2)), Ok(()), "the bound itself passes");
    }

    #[test]
    fn absurd_but_finite_log_probs_and_inputs_are_refused() {
        for (lp, ok) in [
            (-3e38, false),
            (-100.5, false),
            (6.0, false),
            (-100.0, true),
            (5.0, true),
        ] {
            let mut f = fragment();
            f.logp[1] = lp;
            let got = f.validate(&bounds(2));
            assert_eq!(got.is_ok(), ok, "logp {lp}: {got:?}");
            if !ok {
                assert!(matches!(
                    got,
                    Err(ValidationError::Range {
                        field: "logp",
                        index: 1,
                        ..
                    })
                ));
            }
        }
        let mut f = fragment();
        f.x[3] = 2e6;
        assert!(matches!(
            f.validate(&bounds(2)),
            Err(ValidationError::Bound {
                field: "x",
                index: 3,
                ..
            })
        ));
        let mut f = fragment();
        f.last_next_x[0] = -3e38;
        assert!(f.validate(&bounds(2)).is_err());
        let mut f = fragment();
        f.truncated_next_x[1] = 1e30;
        assert!(f.validate(&bounds(2)).is_err());
    }

    #[test]
    fn empty_fragments_and_more_episodes_than_ends_are_refused() {
        let mut f = fragment();
        f.x.clear();
        f.rewards.clear();
        f.logp.clear();
        f.terminated.clear();
        f.truncated.clear();
        f.truncated_next_x.clear();
        f.actions = ActionBatch::Continuous {
            dim: 1,
            data: vec![],
        };
        assert_eq!(
            f.validate(&bounds(2)),
            Err(ValidationError::Empty { field: "rewards" })
        );
        let episode = |ret, length| EpisodeStat {
            ret,
            length,
            success: None,
        };
        // one step of the two ends an episode (truncated)
        let mut f = fragment();
        f.episodes = vec![episode(1.0, 2)];
        assert_eq!(f.validate(&bounds(2)), Ok(()));
        f.episodes = vec![episode(1.0, 2); 2];
        assert!(matches!(
            f.validate(&bounds(2)),
            Err(ValidationError::Length {
                expected: 1,
                got: 2,
                ..
            })
        ));
        for bad in [
            episode(1.0, 0),
            episode(2.1e6, 2),
            episode(f64::INFINITY, 9),
            episode(1.0, 1001),
            episode(1.7e308, u32::MAX),
        ] {
            f.episodes = vec![bad];
            assert!(
                matches!(
                    f.validate(&bounds(2)),
                    Err(ValidationError::Episode { index: 0, .. })
                ),
                "{:?}",
                f.episodes
            );
        }
    }

    #[test]
    fn out_of_range_states_are_refused() {
        let batch = TransitionBatch {
            actor_id: 0,
            states: StateBatch::Categorical {
                factors: 1,
                data: vec![5],
            },
            actions: ActionBatch::Discrete(vec![0]),
            rewards: vec![0.0],
            next_states: StateBatch::Categorical {
                factors: 1,
                data: vec![0],
            },
            terminated: vec![false],
        };
        let err = batch.validate(
            &StateSpace::discrete(5),
            &ActionSpace::Discrete { n: 2 },
            1e6,
        );
        assert!(matches!(
            err,
            Err(ValidationError::OutOfRange { value: 5, .. })
        ));
    }
}
