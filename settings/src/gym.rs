//! A gym run's settings completed from the environment itself: the Python that runs its
//! workers, and what `python -m jsae.envs --describe --env ID` says of its spaces and time
//! limit, laid into `[environment.gym]`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use jsae_env_spec::GymSpace;

use crate::{EnvName, TrainConfig};

/// The environment variable naming the Python that runs the workers.
pub const PYTHON_ENV: &str = "JSAE_PYTHON";

/// The Python interpreter for workers and for describing an environment.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os(PYTHON_ENV).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let cwd = std::env::current_dir().unwrap_or_default();
    cwd.ancestors()
        .map(|dir| dir.join(".venv/bin/python"))
        .find(|p| p.is_file())
        .unwrap_or_else(|| PathBuf::from("python3"))
}

/// Why `python` could not be started for `what`, and what to do about it.
pub fn cannot_start_python(python: &Path, what: &str, e: &std::io::Error) -> String {
    format!(
        "cannot start {} for {what} ({e}): set {PYTHON_ENV} to a Python with the jsae \
         package (pip install ./python), or run scripts/setup-python.sh",
        python.display()
    )
}

/// What `python -m jsae.envs --describe --env ID` says of an environment: its spaces and
/// time limit, as TOML (the keys of `[environment.gym]`, so that infinite bounds are
/// written as they are).
#[derive(Debug, Clone, PartialEq)]
pub struct Description {
    /// The observation space.
    pub observation: GymSpace,
    /// The action space.
    pub action: GymSpace,
    /// `max_episode_steps` (0: none).
    pub max_steps: u32,
}

/// Asks the environment for its spaces, with the Python of [`python`].
pub fn describe(env_id: &str) -> Result<Description, String> {
    let python = python();
    let out = Command::new(&python)
        .args(["-m", "jsae.envs", "--describe", "--env", env_id])
        .stdin(Stdio::null())
        .output()
        .map_err(|e| cannot_start_python(&python, "describing the environment", &e))?;
    if !out.status.success() {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err
            .lines()
            .rev()
            .find(|l| !l.trim().is_empty())
            .unwrap_or("");
        return Err(format!(
            "{} -m jsae.envs --describe --env {env_id} failed ({}): {last}",
            python.display(),
            out.status
        ));
    }
    parse_description(&String::from_utf8_lossy(&out.stdout))
}

/// Reads a description: `observation = {...}`, `action = {...}` and `max_steps = N` in
/// TOML, each space as `environment.gym` holds it.
pub fn parse_description(text: &str) -> Result<Description, String> {
    #[derive(serde::Deserialize)]
    struct Line {
        observation: GymSpace,
        action: GymSpace,
        #[serde(default)]
        max_steps: Option<u32>,
    }
    let l: Line =
        toml::from_str(text).map_err(|e| format!("the environment's description {text:?}: {e}"))?;
    l.observation.check("observation")?;
    l.action.check("action")?;
    Ok(Description {
        observation: l.observation,
        action: l.action,
        max_steps: l.max_steps.unwrap_or(0),
    })
}

/// Where `config` is a gym run whose spaces are not known yet, asks the environment
/// ([`describe`]) and lays its answer into `[environment.gym]` (a time limit already set
/// is kept).
pub fn complete_gym(config: &mut TrainConfig) -> Result<(), String> {
    let gym = &mut config.environment.gym;
    if config.env != EnvName::Gym || (gym.observation.is_some() && gym.action.is_some()) {
        return Ok(());
    }
    if gym.id.is_empty() {
        return Err("--env gym needs an id: --env gym:ID (e.g. gym:CartPole-v1)".into());
    }
    let d = describe(&gym.id)?;
    gym.observation = Some(d.observation);
    gym.action = Some(d.action);
    if gym.max_steps == 0 {
        gym.max_steps = d.max_steps;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_description_line_is_read_and_checked() {
        let d = parse_description(
            "observation = { box = { shape = [2], low = [-1.5, -inf], high = [1.5, inf] } }\n\
             action = { discrete = { n = 2, start = 0 } }\nmax_steps = 500\n",
        )
        .expect("reads");
        assert_eq!(d.max_steps, 500);
        assert_eq!(d.action, GymSpace::Discrete { n: 2, start: 0 });
        let GymSpace::Box { high, .. } = d.observation else {
            panic!("a box")
        };
        assert_eq!(high, vec![1.5, f32::INFINITY]);
        let empty = "observation = { discrete = { n = 0 } }\naction = { discrete = { n = 2 } }";
        assert!(parse_description(empty).is_err());
    }
}
