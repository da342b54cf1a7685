//! A sweep file: which runs an experiment is made of (envs x algos x seeds x settings), and
//! where each run's directory and settings file go inside the sweep's results folder.
//!
//! ```toml
//! envs = ["gridworld-discrete"]
//! algos = ["jsae", "ppo"]
//! seeds = [101, 102, 103]        # or: seeds = { first = 101, count = 10 }
//! env_steps = 1_000_000
//! eval_episodes = 20             # optional
//! one_process = true             # optional (default true: deterministic, cheaper)
//!
//! [report]                       # optional
//! threshold = 0.9                # steps until the training curve first reaches it
//! column = "success_rate"        # of metrics.csv (default: success_rate)
//!
//! [settings.a9.environment.gridworld]   # one setting: a `--config` overlay, named
//! actuators = 9
//! [settings.a12.environment.gridworld]
//! actuators = 12
//! ```
//! A setting may warm-start each run from the matching run of an earlier sweep:
//! `init_from = "runs/sweeps/NAME/runs/SETTING/{env}-{algo}-seed{seed}"` (`{env}`, `{algo}`
//! and `{seed}` are filled in per run; the path is relative to where `jsae sweep` runs).
//! Without `[settings]` there is one setting, `default`, with no overlay.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use jsae_settings::{Algo, EnvName};
use serde::Deserialize;

/// Why a sweep file was refused.
#[derive(Debug, thiserror::Error)]
pub enum GridError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a valid sweep.
    #[error("{path}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// The seeds of a sweep: a list, or `count` consecutive seeds from `first`.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum Seeds {
    List(Vec<u64>),
    Range { first: u64, count: u64 },
}

/// What `jsae report` measures besides the final evaluation.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReportSpec {
    /// The `metrics.csv` column whose curve is plotted and tested against the threshold.
    pub column: String,
    /// Steps to threshold: the first env step at which `column` is at least this.
    pub threshold: Option<f64>,
}

impl Default for ReportSpec {
    fn default() -> Self {
        Self {
            column: "success_rate".into(),
            threshold: None,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GridFile {
    envs: Vec<EnvName>,
    algos: Vec<Algo>,
    seeds: Seeds,
    env_steps: u64,
    eval_episodes: Option<usize>,
    one_process: Option<bool>,
    #[serde(default)]
    report: ReportSpec,
    #[serde(default)]
    settings: BTreeMap<String, toml::Table>,
}

/// A parsed sweep.
#[derive(Debug, Clone)]
pub struct Grid {
    /// Environments.
    pub envs: Vec<EnvName>,
    /// Algorithms.
    pub algos: Vec<Algo>,
    /// Seeds.
    pub seeds: Vec<u64>,
    /// Env steps of every run.
    pub env_steps: u64,
    /// Evaluation episodes (None: each environment's default).
    pub eval_episodes: Option<usize>,
    /// Runs in one process (true) or as services over loopback.
    pub one_process: bool,
    /// What the report measures.
    pub report: ReportSpec,
    /// Named settings overlays (sorted by name).
    pub settings: Vec<(String, toml::Table)>,
}

/// One run of a sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct RunSpec {
    /// The setting's name.
    pub setting: String,
    /// Environment.
    pub env: EnvName,
    /// Algorithm.
    pub algo: Algo,
    /// Seed.
    pub seed: u64,
}

impl RunSpec {
    /// The run's directory, relative to the results folder:
    /// `runs/SETTING/ENV-ALGO-seedN` (one home for the layout: sweep and report both use it).
    pub fn relative_dir(&self) -> PathBuf {
        Path::new("runs").join(&self.setting).join(format!(
            "{}-{}-seed{}",
            self.env.as_str(),
            self.algo.as_str(),
            self.seed
        ))
    }
}

/// Settings names become folder names: letters, digits, `-`, `_` and `.` only.
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

impl Grid {
    /// Reads and checks a sweep file.
    pub fn read(path: &Path) -> Result<Self, GridError> {
        let text = std::fs::read_to_string(path).map_err(|source| GridError::Read {
            path: path.into(),
            source,
        })?;
        Self::parse(&text).map_err(|message| GridError::Invalid {
            path: path.into(),
            message,
        })
    }

    /// Parses and checks a sweep file's text.
    pub fn parse(text: &str) -> Result<Self, String> {
        let file: GridFile = toml::from_str(text).map_err(|e| e.to_string())?;
        let seeds = match file.seeds {
            Seeds::List(v) => v,
            Seeds::Range { first, count } => (first..first.saturating_add(count)).collect(),
        };
        let unique = |n: usize, what: &str| {
            if n == 0 {
                Err(format!("{what} must not be empty"))
            } else {
                Ok(())
            }
        };
        unique(file.envs.len(), "envs")?;
        unique(file.algos.len(), "algos")?;
        unique(seeds.len(), "seeds")?;
        if seeds.iter().any(|&s| i64::try_from(s).is_err()) {
            return Err("seeds must be below 2^63".into());
        }
        let mut sorted = seeds.clone();
        sorted.sort_unstable();
        sorted.dedup();
        if sorted.len() != seeds.len() {
            return Err("seeds must not repeat".into());
        }
        if file.env_steps == 0 {
            return Err("env_steps must be positive".into());
        }
        if file.eval_episodes == Some(0) {
            return Err("eval_episodes must be positive".into());
        }
        let mut settings: Vec<(String, toml::Table)> = file.settings.into_iter().collect();
        for (name, overlay) in &settings {
            if !valid_name(name) {
                return Err(format!(
                    "setting name {name:?}: use letters, digits, '-', '_' and '.'"
                ));
            }
            for key in ["env", "algo", "seed", "env_steps", "out", "one_process"] {
                if overlay.contains_key(key) {
                    return Err(format!(
                        "setting {name}: `{key}` is the sweep's to set, not a setting's"
                    ));
                }
            }
        }
        if settings.is_empty() {
            settings.push(("default".into(), toml::Table::new()));
        }
        Ok(Self {
            envs: file.envs,
            algos: file.algos,
            seeds,
            env_steps: file.env_steps,
            eval_episodes: file.eval_episodes,
            one_process: file.one_process.unwrap_or(true),
            report: file.report,
            settings,
        })
    }

    /// Every run, setting by setting, then env, algo and seed; seeds vary fastest.
    pub fn runs(&self) -> Vec<RunSpec> {
        let mut runs = Vec::new();
        for (setting, _) in &self.settings {
            for &env in &self.envs {
                for &algo in &self.algos {
                    for &seed in &self.seeds {
                        runs.push(RunSpec {
                            setting: setting.clone(),
                            env,
                            algo,
                            seed,
                        });
                    }
                }
            }
        }
        runs
    }

    /// The `--config` file of one run: the setting's overlay with the sweep's own keys.
    pub fn run_config(&self, run: &RunSpec) -> toml::Table {
        let mut table = self
            .settings
            .iter()
            .find(|(name, _)| *name == run.setting)
            .map(|(_, t)| t.clone())
            .unwrap_or_default();
        let s = |v: &str| toml::Value::String(v.into());
        let int = |v: u64| toml::Value::Integer(i64::try_from(v).unwrap_or(i64::MAX));
        table.insert("env".into(), s(run.env.as_str()));
        table.insert("algo".into(), s(run.algo.as_str()));
        table.insert("seed".into(), int(run.seed));
        table.insert("env_steps".into(), int(self.env_steps));
        table.insert("one_process".into(), toml::Value::Boolean(self.one_process));
        if let Some(n) = self.eval_episodes {
            table.insert("eval_episodes".into(), int(n as u64));
        }
        // A warm start names the matching run of another sweep: `{env}`, `{algo}` and `{seed}`
        // in `init_from` are this run's.
        if let Some(toml::Value::String(from)) = table.get("init_from") {
            let from = from
                .replace("{env}", run.env.as_str())
                .replace("{algo}", run.algo.as_str())
                .replace("{seed}", &run.seed.to_string());
            table.insert("init_from".into(), s(&from));
        }
        table
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = r#"
        envs = ["gridworld-discrete", "slotmachine"]
        algos = ["jsae", "ppo"]
        seeds = { first = 101, count = 3 }
        env_steps = 50_000
        [report]
        threshold = 0.9
        [settings.a9.environment.gridworld]
        actuators = 9
        [settings.a10.environment.gridworld]
        actuators = 10
    "#;

    #[test]
    fn a_grid_is_the_product_of_its_lists() {
        let g = Grid::parse(FILE).expect("valid");
        assert_eq!(g.seeds, vec![101, 102, 103]);
        let runs = g.runs();
        assert_eq!(runs.len(), 2 * 2 * 2 * 3);
        // Settings sorted by name, seeds fastest.
        assert_eq!(runs[0].setting, "a10");
        assert_eq!((runs[0].seed, runs[1].seed), (101, 102));
        assert_eq!(
            runs[0].relative_dir(),
            Path::new("runs/a10/gridworld-discrete-jsae-seed101")
        );
        let config = g.run_config(&runs[0]);
        assert_eq!(config["seed"].as_integer(), Some(101));
        assert_eq!(
            config["environment"]["gridworld"]["actuators"].as_integer(),
            Some(10)
        );
        assert_eq!(config["one_process"].as_bool(), Some(true));
        assert_eq!(g.report.threshold, Some(0.9));
        assert_eq!(g.report.column, "success_rate");
    }

    #[test]
    fn a_warm_start_names_the_matching_run_of_each_seed() {
        let text = "envs = [\"gridworld-discrete\"]\nalgos = [\"jsae\"]\nseeds = [7, 8]\n\
                    env_steps = 10\n[settings.warm]\n\
                    init_from = \"src/runs/a9/{env}-{algo}-seed{seed}\"\n";
        let g = Grid::parse(text).expect("valid");
        let runs = g.runs();
        assert_eq!(
            g.run_config(&runs[1])["init_from"].as_str(),
            Some("src/runs/a9/gridworld-discrete-jsae-seed8")
        );
    }

    #[test]
    fn bad_sweeps_are_refused_with_a_reason() {
        let base = "envs = [\"slotmachine\"]\nalgos = [\"ppo\"]\nenv_steps = 10\n";
        let err = |extra: &str| Grid::parse(&format!("{base}{extra}")).expect_err("refused");
        assert!(err("seeds = [1, 1]").contains("repeat"));
        assert!(err("seeds = []").contains("seeds"));
        assert!(err("seeds = [1]\n[settings.\"a/b\"]\nx = 1").contains("setting name"));
        assert!(err("seeds = [1]\n[settings.s]\nseed = 3").contains("sweep's to set"));
        assert!(err("seeds = [1]\nbogus = 3").contains("bogus"));
        let one = Grid::parse(&format!("{base}seeds = [4]")).expect("valid");
        assert_eq!(one.settings[0].0, "default");
        assert_eq!(one.runs().len(), 1);
    }
}
