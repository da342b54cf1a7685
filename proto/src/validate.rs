//! Input checks every receiver runs before accepting a message.

use crate::{ActionBatch, ActionSpace, RolloutFragment, StateBatch, StateSpace, TransitionBatch};

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
            check_finite(field, data)
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

impl TransitionBatch {
    /// Checks dimensions, ranges and finiteness against the environment's spaces.
    pub fn validate(
        &self,
        states: &StateSpace,
        actions: &ActionSpace,
    ) -> Result<(), ValidationError> {
        let n = self.rewards.len();
        check_states("states", &self.states, states, n)?;
        check_states("next_states", &self.next_states, states, n)?;
        check_actions("actions", &self.actions, actions, n)?;
        check_len("terminated", n, self.terminated.len())?;
        check_finite("rewards", &self.rewards)
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

impl RolloutFragment {
    /// Checks dimensions and finiteness against the policy's input width and action space
    /// (`policy_actions`: the space the policy samples in), and that no reward is larger in
    /// magnitude than `max_abs_reward` (`ppo.max_abs_reward`).
    pub fn validate(
        &self,
        x_dim: usize,
        policy_actions: &ActionSpace,
        max_abs_reward: f32,
    ) -> Result<(), ValidationError> {
        let n = self.rewards.len();
        check_len("x_dim", x_dim, self.x_dim)?;
        check_len("x", n * x_dim, self.x.len())?;
        check_finite("x", &self.x)?;
        check_actions("actions", &self.actions, policy_actions, n)?;
        check_len("logp", n, self.logp.len())?;
        check_finite("logp", &self.logp)?;
        check_finite("rewards", &self.rewards)?;
        check_bound("rewards", &self.rewards, max_abs_reward)?;
        check_len("terminated", n, self.terminated.len())?;
        check_len("truncated", n, self.truncated.len())?;
        let cuts = self.truncated.iter().filter(|&&t| t).count();
        check_len(
            "truncated_next_x",
            cuts * x_dim,
            self.truncated_next_x.len(),
        )?;
        check_finite("truncated_next_x", &self.truncated_next_x)?;
        check_len("last_next_x", x_dim, self.last_next_x.len())?;
        check_finite("last_next_x", &self.last_next_x)?;
        if !self.visit_keys.is_empty() {
            check_len("visit_keys", n, self.visit_keys.len())?;
        }
        Ok(())
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

    #[test]
    fn a_consistent_fragment_passes() {
        assert_eq!(fragment().validate(2, &space(), 1e6), Ok(()));
    }

    #[test]
    fn wrong_dimensions_nan_and_missing_bootstrap_are_refused() {
        let mut f = fragment();
        f.x.pop();
        assert!(matches!(
            f.validate(2, &space(), 1e6),
            Err(ValidationError::Length { field: "x", .. })
        ));
        let mut f = fragment();
        f.rewards[0] = f32::NAN;
        assert!(matches!(
            f.validate(2, &space(), 1e6),
            Err(ValidationError::NotFinite { .. })
        ));
        let mut f = fragment();
        f.truncated_next_x.clear();
        assert!(f.validate(2, &space(), 1e6).is_err());
        assert!(fragment().validate(3, &space(), 1e6).is_err());
        let mut f = fragment();
        f.visit_keys = vec![7];
        assert!(matches!(
            f.validate(2, &space(), 1e6),
            Err(ValidationError::Length {
                field: "visit_keys",
                ..
            })
        ));
        f.visit_keys = vec![7, 8];
        assert_eq!(f.validate(2, &space(), 1e6), Ok(()), "one key a step");
    }

    #[test]
    fn finite_rewards_beyond_the_bound_are_refused() {
        let mut f = fragment();
        f.rewards[1] = 3e38;
        assert_eq!(
            f.validate(2, &space(), 1e6),
            Err(ValidationError::Bound {
                field: "rewards",
                index: 1,
                value: 3e38,
                limit: 1e6
            })
        );
        f.rewards[1] = -1e6;
        assert_eq!(
            f.validate(2, &space(), 1e6),
            Ok(()),
            "the bound itself passes"
        );
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
        let err = batch.validate(&StateSpace::discrete(5), &ActionSpace::Discrete { n: 2 });
        assert!(matches!(
            err,
            Err(ValidationError::OutOfRange { value: 5, .. })
        ));
    }
}
