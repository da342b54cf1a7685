//! Running a sweep: every run of the grid as its own `jsae train` process, `jobs` at a
//! time, into one results folder. A run whose `summary.json` exists is finished and skipped,
//! so an interrupted sweep goes on where it stopped when started again.
//!
//! The results folder holds `sweep.toml` (the sweep file the runs came from), `configs/`
//! (each run's `--config` file), `logs/` (each run's output) and `runs/` (the run
//! directories; see [`RunSpec::relative_dir`]).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use jsae_run_dir::RunDir;
use jsae_settings::{ConfigError, TrainConfig};

use crate::grid::{Grid, RunSpec};

/// Why a sweep could not start (a run that fails is reported in [`SweepOutcome`] instead).
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// The results folder could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Another sweep is running into the same folder.
    #[error("{path}: another sweep (pid {pid}) is running into this folder")]
    Busy {
        /// The lock file.
        path: PathBuf,
        /// Its pid.
        pid: String,
    },
    /// A run's settings are refused (checked for every run before any starts).
    #[error("{run}: {reason}")]
    Settings {
        /// The run.
        run: String,
        /// Why.
        reason: String,
    },
    /// SIGTERM or SIGINT arrived: the running runs were stopped and no other started.
    #[error(
        "stopped by a signal: {trained} runs finished before it; the {stopped} it stopped \
         start again from nothing at the next `jsae sweep` into this folder"
    )]
    Interrupted {
        /// Runs that finished in this sweep.
        trained: usize,
        /// Runs it stopped.
        stopped: usize,
    },
    /// The signal handlers could not be installed.
    #[error("cannot catch SIGTERM and SIGINT: {0}")]
    Signals(std::io::Error),
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> SweepError + '_ {
    move |source| SweepError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// How to run a sweep.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    /// The `jsae` executable each run is started with.
    pub exe: PathBuf,
    /// Runs at a time.
    pub jobs: usize,
    /// The results folder.
    pub out: PathBuf,
}

/// What a sweep did.
#[derive(Debug, Default)]
pub struct SweepOutcome {
    /// Runs trained now.
    pub trained: usize,
    /// Runs already finished before (skipped).
    pub skipped: usize,
    /// Runs that failed, with the log to read.
    pub failed: Vec<(RunSpec, PathBuf)>,
}

/// Where one run's files go inside the results folder.
#[derive(Debug, Clone)]
pub struct RunPaths {
    /// The run directory.
    pub dir: PathBuf,
    /// Its `--config` file.
    pub config: PathBuf,
    /// Its output.
    pub log: PathBuf,
}

impl RunPaths {
    /// The paths of `run` under the results folder `out`.
    pub fn new(out: &Path, run: &RunSpec) -> Self {
        let rel = run.relative_dir();
        let under = |top: &str, ext: &str| {
            let mut p = out.join(top).join(rel.strip_prefix("runs").unwrap_or(&rel));
            p.set_extension(ext);
            p
        };
        Self {
            dir: out.join(&rel),
            config: under("configs", "toml"),
            log: under("logs", "log"),
        }
    }

    /// Whether the run finished (its summary is there and reads).
    pub fn finished(&self) -> bool {
        let summary = RunDir::new(&self.dir).summary_json();
        std::fs::read_to_string(summary)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some()
    }
}

/// Threads the learner of one run may use when `jobs` runs share this machine's cores.
fn threads_per_run(jobs: usize) -> usize {
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    (cores / jobs.max(1)).max(1)
}

/// The sweep's lock: `DIR/sweep.lock` holds the pid of the sweep running into `DIR`, so a
/// second one started on the same folder (which would restart the first one's unfinished
/// runs under it) is refused. Removed when dropped.
#[derive(Debug)]
struct Lock(PathBuf);

impl Lock {
    fn take(out: &Path) -> Result<Self, SweepError> {
        let path = out.join("sweep.lock");
        if let Ok(pid) = std::fs::read_to_string(&path) {
            let pid = pid.trim();
            let alive = !pid.is_empty() && Path::new("/proc").join(pid).exists();
            if alive && pid != std::process::id().to_string() {
                return Err(SweepError::Busy {
                    path,
                    pid: pid.to_string(),
                });
            }
        }
        std::fs::write(&path, format!("{}\n", std::process::id())).map_err(io(&path))?;
        Ok(Self(path))
    }
}

impl Drop for Lock {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The runs of `grid` still to train in `out`, each with its paths and settings file (the
/// finished ones counted as skipped); every one's settings checked first.
fn unfinished_runs(
    grid: &Grid,
    out: &Path,
    outcome: &mut SweepOutcome,
) -> Result<Vec<(RunSpec, RunPaths, String)>, SweepError> {
    let mut todo = Vec::new();
    let check = out.join(".settings-check.toml");
    for run in grid.runs() {
        let paths = RunPaths::new(out, &run);
        let name = || run.relative_dir().display().to_string();
        let config = toml::to_string(&grid.run_config(&run)).map_err(|e| SweepError::Settings {
            run: name(),
            reason: e.to_string(),
        })?;
        let same = std::fs::read_to_string(&paths.config).is_ok_and(|old| old == config);
        if same && paths.finished() {
            outcome.skipped += 1;
            continue;
        }
        std::fs::write(&check, &config).map_err(io(&check))?;
        // a gym run's spaces come from its environment, as `jsae train` asks them
        TrainConfig::from_layers(None, None, Some(&check))
            .and_then(|mut c| {
                jsae_settings::complete_gym(&mut c).map_err(ConfigError::Invalid)?;
                c.validate()
            })
            .map_err(|e| SweepError::Settings {
                run: name(),
                reason: e.to_string(),
            })?;
        todo.push((run, paths, config));
    }
    let _ = std::fs::remove_file(&check);
    Ok(todo)
}

/// Runs every unfinished run of `grid`; `note` hears one line per started and ended run.
///
/// A run is finished when its `summary.json` reads and its `--config` file is the one this
/// grid gives it; a run of an edited grid (other env steps, another overlay) is trained
/// again. Every run's settings are checked before anything is written or started.
pub fn run_sweep(
    grid: &Grid,
    sweep_text: &str,
    options: &SweepOptions,
    note: &(dyn Fn(&str) + Sync),
) -> Result<SweepOutcome, SweepError> {
    let out = &options.out;
    std::fs::create_dir_all(out).map_err(io(out))?;
    let _lock = Lock::take(out)?;
    let mut outcome = SweepOutcome::default();
    let todo = unfinished_runs(grid, out, &mut outcome)?;
    let sweep_file = out.join("sweep.toml");
    std::fs::write(&sweep_file, sweep_text).map_err(io(&sweep_file))?;
    let mut queue = VecDeque::new();
    for (run, paths, config) in todo {
        if paths.dir.exists() {
            // An interrupted run, or one of an edited grid: start it again from nothing.
            std::fs::remove_dir_all(&paths.dir).map_err(io(&paths.dir))?;
        }
        for file in [&paths.config, &paths.log] {
            if let Some(parent) = file.parent() {
                std::fs::create_dir_all(parent).map_err(io(parent))?;
            }
        }
        std::fs::write(&paths.config, config).map_err(io(&paths.config))?;
        queue.push_back((run, paths));
    }
    let total = queue.len();
    let stop = crate::child::stop_on_signal().map_err(SweepError::Signals)?;
    let stopped = AtomicUsize::new(0);
    note(&format!(
        "{total} runs to train, {} finished before; {} at a time",
        outcome.skipped, options.jobs
    ));
    let queue = Mutex::new(queue);
    let results = Mutex::new(Vec::new());
    let threads = threads_per_run(options.jobs);
    std::thread::scope(|scope| {
        for _ in 0..options.jobs.max(1) {
            scope.spawn(|| {
                loop {
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                    let next = queue.lock().map(|mut q| q.pop_front()).ok().flatten();
                    let Some((run, paths)) = next else { break };
                    let started = Instant::now();
                    let Some(ok) = train_one(&options.exe, &paths, threads, &stop) else {
                        stopped.fetch_add(1, Ordering::Relaxed);
                        note(&format!("stopped {}", run.relative_dir().display()));
                        continue;
                    };
                    let mut done = results.lock().unwrap_or_else(|e| e.into_inner());
                    done.push((run.clone(), paths.clone(), ok));
                    note(&format!(
                        "[{}/{total}] {} {} in {:.0} s",
                        done.len(),
                        if ok { "finished" } else { "FAILED" },
                        run.relative_dir().display(),
                        started.elapsed().as_secs_f64()
                    ));
                }
            });
        }
    });
    for (run, paths, ok) in results.into_inner().unwrap_or_else(|e| e.into_inner()) {
        if ok {
            outcome.trained += 1;
        } else {
            outcome.failed.push((run, paths.log));
        }
    }
    if stop.load(Ordering::Relaxed) {
        return Err(SweepError::Interrupted {
            trained: outcome.trained,
            stopped: stopped.into_inner(),
        });
    }
    Ok(outcome)
}

/// How long a stopped run's `jsae train` has to stop its services (SIGTERM) before it is
/// killed: its own services have 10-30 s each.
const RUN_STOP_TIMEOUT: Duration = Duration::from_secs(60);

/// Trains one run as a `jsae train` process: whether it finished with a summary, or None
/// when `stop` was set meanwhile (the process was then stopped with SIGTERM, passed on to
/// its services, and SIGKILL after [`RUN_STOP_TIMEOUT`]).
fn train_one(exe: &Path, paths: &RunPaths, threads: usize, stop: &AtomicBool) -> Option<bool> {
    let Ok(log) = std::fs::File::create(&paths.log) else {
        return Some(false);
    };
    let Ok(log2) = log.try_clone() else {
        return Some(false);
    };
    let mut command = Command::new(exe);
    // The run's settings are its --config file alone: the `jsae train` flags' environment
    // variables would override them.
    for var in [
        "JSAE_ENV_STEPS",
        "JSAE_ACTORS",
        "JSAE_ENVS",
        "JSAE_OUT",
        "JSAE_DEVICE",
        "JSAE_EVAL_EPISODES",
        "JSAE_ENV",
        "JSAE_ALGO",
        "JSAE_SEED",
        "JSAE_CONFIG",
        "JSAE_INIT_FROM",
    ] {
        command.env_remove(var);
    }
    let child = command
        .arg("train")
        .arg("--config")
        .arg(&paths.config)
        .arg("--out")
        .arg(&paths.dir)
        .arg("--quiet")
        .env("RAYON_NUM_THREADS", threads.to_string())
        .stdin(Stdio::null())
        .stdout(log)
        .stderr(log2)
        .spawn();
    let Ok(mut child) = child else {
        return Some(false);
    };
    loop {
        if stop.load(Ordering::Relaxed) {
            crate::child::terminate(&mut child, RUN_STOP_TIMEOUT);
            return None;
        }
        match child.try_wait() {
            Ok(Some(status)) => return Some(status.success() && paths.finished()),
            Ok(None) => std::thread::sleep(Duration::from_millis(100)),
            Err(_) => {
                let _ = child.kill();
                let _ = child.wait();
                return Some(false);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jsae_settings::{Algo, EnvName};

    #[test]
    fn run_files_live_beside_each_other() {
        let run = RunSpec {
            setting: "a9".into(),
            env: EnvName::Slotmachine,
            algo: Algo::Ppo,
            seed: 7,
        };
        let p = RunPaths::new(Path::new("/r"), &run);
        assert_eq!(p.dir, Path::new("/r/runs/a9/slotmachine-ppo-seed7"));
        assert_eq!(
            p.config,
            Path::new("/r/configs/a9/slotmachine-ppo-seed7.toml")
        );
        assert_eq!(p.log, Path::new("/r/logs/a9/slotmachine-ppo-seed7.log"));
        assert!(!p.finished());
    }
}
