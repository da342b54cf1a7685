//! A worker's observations and the actor's actions in their wire form, for one space: what
//! is decoded is checked against the run's spaces first (the shape, the range of every
//! value), and refused with the reason.

use jsae_envs::{ActionRef, GymSpace};
use jsae_wire::{MAX_ABS_POLICY_INPUT, StateBatch, pb};

/// The most magnitude a reward may have.
pub const MAX_ABS_REWARD: f64 = 1e9;

/// How a space's observations and actions travel.
#[derive(Debug, Clone)]
pub(crate) struct SpaceCodec {
    observation: GymSpace,
}

impl SpaceCodec {
    pub(crate) fn new(observation: GymSpace) -> Self {
        Self { observation }
    }

    /// Appends the `rows` observations of `obs` to `out` (a batch of the run's state
    /// space), or says why they do not fit.
    pub(crate) fn decode_observations(
        &self,
        obs: Option<&pb::Observations>,
        rows: usize,
        out: &mut StateBatch,
    ) -> Result<(), String> {
        let empty = pb::Observations::default();
        let obs = obs.unwrap_or(&empty);
        match (&self.observation, out) {
            (GymSpace::Box { shape, .. }, StateBatch::Real { dim, data }) => {
                if !obs.index.is_empty() {
                    return Err(format!("indices for a Box{shape:?} observation"));
                }
                let want = rows * *dim * 4;
                if obs.real.len() != want {
                    return Err(format!(
                        "{} bytes of observations, expected {want} ({rows} of Box{shape:?}, float32)",
                        obs.real.len()
                    ));
                }
                let start = data.len();
                data.extend(
                    obs.real
                        .chunks_exact(4)
                        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                );
                if let Some(v) = data[start..]
                    .iter()
                    .find(|v| !v.is_finite() || v.abs() > MAX_ABS_POLICY_INPUT)
                    .copied()
                {
                    data.truncate(start);
                    return Err(format!(
                        "an observation value {v} (NaN, infinite or beyond {MAX_ABS_POLICY_INPUT:e})"
                    ));
                }
                Ok(())
            }
            (space, StateBatch::Categorical { factors, data }) => {
                let sizes: Vec<u64> = match space {
                    GymSpace::Discrete { n, .. } => vec![*n],
                    GymSpace::MultiDiscrete { nvec } => nvec.clone(),
                    GymSpace::Box { .. } => unreachable!("a box observes real states"),
                };
                if !obs.real.is_empty() {
                    return Err(format!(
                        "real values for a {} observation",
                        space.describe()
                    ));
                }
                if obs.index.len() != rows * *factors {
                    return Err(format!(
                        "{} observation indices, expected {} ({rows} of {})",
                        obs.index.len(),
                        rows * *factors,
                        space.describe()
                    ));
                }
                for (k, &v) in obs.index.iter().enumerate() {
                    let size = sizes[k % sizes.len()];
                    if u64::from(v) >= size {
                        return Err(format!(
                            "observation index {v} of a component with {size} values"
                        ));
                    }
                }
                data.extend_from_slice(&obs.index);
                Ok(())
            }
            (space, _) => Err(format!(
                "{} observations do not fit the run's states",
                space.describe()
            )),
        }
    }

    /// Appends one action to `command` (a step command being built).
    pub(crate) fn encode_action(&self, action: ActionRef<'_>, command: &mut pb::StepCommand) {
        match action {
            ActionRef::Discrete(a) => command.discrete.push(a),
            ActionRef::Continuous(v) => {
                for x in v {
                    command.continuous.extend_from_slice(&x.to_le_bytes());
                }
            }
        }
    }
}

/// Checks a step's reply fields: one reward, `terminated` and `truncated` per row, rewards
/// finite and within `max_abs_reward`, never both ended flags on one row; and one reset
/// observation row per ended episode (checked by the caller's decode).
pub(crate) fn check_step_reply(
    reply: &pb::EnvReply,
    rows: usize,
    max_abs_reward: f64,
) -> Result<usize, String> {
    if reply.rewards.len() != rows
        || reply.terminated.len() != rows
        || reply.truncated.len() != rows
    {
        return Err(format!(
            "{} rewards, {} terminated and {} truncated flags for {rows} environments",
            reply.rewards.len(),
            reply.terminated.len(),
            reply.truncated.len()
        ));
    }
    if let Some(r) = (reply.rewards.iter()).find(|r| !r.is_finite() || r.abs() > max_abs_reward) {
        return Err(format!(
            "a reward {r} (NaN, infinite or beyond {max_abs_reward:e}, the run's ppo.max_abs_reward)"
        ));
    }
    let mut ended = 0;
    for (t, u) in reply.terminated.iter().zip(&reply.truncated) {
        if *t && *u {
            return Err(
                "a step both terminated and truncated (Gymnasium reports terminated alone then)"
                    .into(),
            );
        }
        ended += usize::from(*t || *u);
    }
    Ok(ended)
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_wire::StateSpace;

    fn boxed(dim: u32) -> GymSpace {
        GymSpace::Box {
            shape: vec![dim],
            low: vec![-1.0; dim as usize],
            high: vec![1.0; dim as usize],
        }
    }

    #[test]
    fn observations_of_the_wrong_shape_or_with_nan_are_refused() {
        let codec = SpaceCodec::new(boxed(2));
        let mut out = StateBatch::empty(&StateSpace::Real { dim: 2 });
        let bytes = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let good = pb::Observations {
            real: bytes(&[0.5, -0.25, 1.0, 2.0]),
            index: vec![],
        };
        codec
            .decode_observations(Some(&good), 2, &mut out)
            .expect("fits");
        assert_eq!(out.len(), 2);
        let short = pb::Observations {
            real: bytes(&[0.5, -0.25, 1.0]),
            index: vec![],
        };
        let err = codec
            .decode_observations(Some(&short), 2, &mut out)
            .expect_err("refused");
        assert!(err.contains("expected 16"), "{err}");
        let nan = pb::Observations {
            real: bytes(&[f32::NAN, 0.0]),
            index: vec![],
        };
        let err = codec
            .decode_observations(Some(&nan), 1, &mut out)
            .expect_err("refused");
        assert!(err.contains("NaN"), "{err}");
        assert_eq!(out.len(), 2, "a refused row is not kept");
    }

    #[test]
    fn indices_beyond_a_component_are_refused() {
        let codec = SpaceCodec::new(GymSpace::MultiDiscrete { nvec: vec![3, 2] });
        let mut out = StateBatch::empty(&StateSpace::Categorical { sizes: vec![3, 2] });
        let good = pb::Observations {
            real: vec![],
            index: vec![2, 1],
        };
        codec
            .decode_observations(Some(&good), 1, &mut out)
            .expect("fits");
        let bad = pb::Observations {
            real: vec![],
            index: vec![1, 2],
        };
        assert!(codec.decode_observations(Some(&bad), 1, &mut out).is_err());
    }

    #[test]
    fn step_replies_are_checked_row_by_row() {
        let reply = pb::EnvReply {
            rewards: vec![1.0, 2.0],
            terminated: vec![true, false],
            truncated: vec![false, false],
            ..pb::EnvReply::default()
        };
        assert_eq!(check_step_reply(&reply, 2, MAX_ABS_REWARD), Ok(1));
        assert!(check_step_reply(&reply, 3, MAX_ABS_REWARD).is_err());
        let both = pb::EnvReply {
            terminated: vec![true],
            truncated: vec![true],
            rewards: vec![0.0],
            ..pb::EnvReply::default()
        };
        assert!(check_step_reply(&both, 1, MAX_ABS_REWARD).is_err());
        let inf = pb::EnvReply {
            terminated: vec![false],
            truncated: vec![false],
            rewards: vec![f64::INFINITY],
            ..pb::EnvReply::default()
        };
        assert!(check_step_reply(&inf, 1, MAX_ABS_REWARD).is_err());
    }
}
