//! `jsae env-replay`: replays a recorded initial state and action sequence through a MuJoCo
//! environment and writes what each step returned, to check it against Gymnasium value for
//! value (docs/src/environments.md). Input: a line `{"qpos": [...], "qvel": [...]}`, then one line
//! `{"action": [...]}` per step; output: one line `{"obs": [...], "reward": r,
//! "terminated": b}` per step (every input step is replayed, as Gymnasium would step on
//! after a terminal one).

use std::io::{BufRead, Write};

use serde::{Deserialize, Serialize};

use jsae_envs::{EnvName, MujocoConfig, MujocoEnv, Robot};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InitialState {
    qpos: Vec<f64>,
    qvel: Vec<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ActionLine {
    action: Vec<f64>,
}

#[derive(Debug, Serialize)]
struct StepLine<'a> {
    obs: &'a [f64],
    reward: f64,
    terminated: bool,
}

/// Why a replay failed; the message names the input line.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// Not a MuJoCo environment.
    #[error("env-replay needs half-cheetah or ant, got {0}")]
    NotMujoco(&'static str),
    /// A line does not parse or has the wrong length.
    #[error("input line {line}: {reason}")]
    Input {
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Reading or writing failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// Replays `input` through `env` and writes one line per step to `output`; returns the
/// number of steps.
pub fn replay(
    env: EnvName,
    input: impl BufRead,
    mut output: impl Write,
) -> Result<usize, ReplayError> {
    let robot = match env {
        EnvName::HalfCheetah => Robot::HalfCheetah,
        EnvName::Ant => Robot::Ant,
        other => return Err(ReplayError::NotMujoco(other.as_str())),
    };
    // No time limit: the input decides how many steps there are.
    let mut mj = MujocoEnv::new(
        robot,
        &MujocoConfig {
            max_steps: u32::MAX,
        },
    );
    let (nq, nv) = mj.state_sizes();
    let nu = match jsae_envs::Env::action_space(&mj) {
        jsae_wire::ActionSpace::Continuous { dim, .. } => *dim,
        jsae_wire::ActionSpace::Discrete { .. } => 0,
    };
    let bad = |line: usize, reason: String| ReplayError::Input { line, reason };
    let mut lines = input.lines().enumerate().filter(|(_, l)| match l {
        Ok(text) => !text.trim().is_empty(),
        Err(_) => true,
    });
    let Some((_, first)) = lines.next() else {
        return Err(bad(
            1,
            "empty input: expected {\"qpos\": [...], \"qvel\": [...]}".into(),
        ));
    };
    let init: InitialState = serde_json::from_str(&first?).map_err(|e| bad(1, e.to_string()))?;
    if init.qpos.len() != nq || init.qvel.len() != nv {
        return Err(bad(
            1,
            format!(
                "qpos/qvel have {}/{} values, the model has nq={nq}, nv={nv}",
                init.qpos.len(),
                init.qvel.len()
            ),
        ));
    }
    mj.reset_to(&init.qpos, &init.qvel);
    let mut steps = 0;
    for (i, line) in lines {
        let number = i + 1;
        let step: ActionLine =
            serde_json::from_str(&line?).map_err(|e| bad(number, e.to_string()))?;
        if step.action.len() != nu {
            return Err(bad(
                number,
                format!("action has {} values, expected {nu}", step.action.len()),
            ));
        }
        if step.action.iter().any(|a| !a.is_finite()) {
            return Err(bad(number, "action values must be finite".into()));
        }
        let out = mj.step_f64(&step.action);
        let line = StepLine {
            obs: mj.observation(),
            reward: out.reward,
            terminated: out.terminated,
        };
        serde_json::to_writer(&mut output, &line).map_err(std::io::Error::from)?;
        output.write_all(b"\n")?;
        steps += 1;
    }
    output.flush()?;
    Ok(steps)
}
