//! Worker processes an actor starts itself: `PYTHON -m jsae.envs --env ID --actor URL
//! --envs N` for each ([`jsae_settings::python`]), their output in a log file (appended to
//! when one is started again), killed when dropped. [`WorkerProcesses::supervise`] starts
//! again a worker that exited, at most [`MAX_RESTARTS`] times, unless the actor refused it
//! (exit status 2: it would be refused again).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use jsae_settings::python;

/// How many times one worker is started again after it exited.
pub const MAX_RESTARTS: u32 = 3;
/// The exit status of a worker the actor refused (`python -m jsae.envs`).
const REFUSED: i32 = 2;

/// How to start an actor's workers.
#[derive(Debug, Clone)]
pub struct WorkerPlan {
    /// The Gymnasium id.
    pub env_id: String,
    /// The actor's environment host, `http://host:port`.
    pub url: String,
    /// Environments in all.
    pub envs: usize,
    /// Processes to share them among (at least one, at most `envs`).
    pub workers: usize,
    /// Where each worker's output goes (`DIR/worker-K.log`); None: inherited.
    pub log_dir: Option<PathBuf>,
    /// Added to each log's name, e.g. the actor's id.
    pub name: String,
    /// The time limit the workers apply (`--max-episode-steps`; 0: the environment's own).
    pub max_steps: u32,
    /// Variables the workers get (the token and CA files the services take).
    pub env: Vec<(&'static str, PathBuf)>,
}

#[derive(Debug)]
struct Managed {
    name: String,
    envs: usize,
    child: Child,
    restarts: u32,
}

/// Worker processes, killed on drop.
#[derive(Debug, Default)]
pub struct WorkerProcesses {
    plan: Option<WorkerPlan>,
    python: PathBuf,
    children: Vec<Managed>,
}

impl WorkerProcesses {
    /// Starts the workers of `plan`.
    pub fn start(plan: &WorkerPlan) -> Result<Self, String> {
        let workers = plan.workers.clamp(1, plan.envs.max(1));
        let mut started = Self {
            plan: Some(plan.clone()),
            python: python(),
            children: Vec::new(),
        };
        for k in 0..workers {
            // the environments shared as evenly as they go, the first ones taking the rest
            let envs = plan.envs / workers + usize::from(k < plan.envs % workers);
            let name = format!("worker-{}{k}", plan.name);
            let child = started.spawn(&name, envs, false)?;
            started.children.push(Managed {
                name,
                envs,
                child,
                restarts: 0,
            });
        }
        Ok(started)
    }

    fn spawn(&self, name: &str, envs: usize, again: bool) -> Result<Child, String> {
        let Some(plan) = &self.plan else {
            return Err("no plan".into());
        };
        let (out, err) = match &plan.log_dir {
            Some(dir) => {
                std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
                let path = dir.join(format!("{name}.log"));
                let file = std::fs::OpenOptions::new()
                    .create(true)
                    .append(again)
                    .write(true)
                    .truncate(!again)
                    .open(&path)
                    .map_err(|e| format!("{}: {e}", path.display()))?;
                let err = file
                    .try_clone()
                    .map_err(|e| format!("{}: {e}", path.display()))?;
                (Stdio::from(file), Stdio::from(err))
            }
            None => (Stdio::inherit(), Stdio::inherit()),
        };
        let mut command = Command::new(&self.python);
        command
            .args([
                "-m",
                "jsae.envs",
                "--env",
                &plan.env_id,
                "--actor",
                &plan.url,
            ])
            .args(["--envs", &envs.to_string(), "--name", name])
            .envs(plan.env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err);
        if plan.max_steps > 0 {
            command.args(["--max-episode-steps", &plan.max_steps.to_string()]);
        }
        command.spawn().map_err(|e| cannot_start(&self.python, &e))
    }

    /// Starts again each worker that exited (at most [`MAX_RESTARTS`] times, never one the
    /// actor refused); the reason when a worker will not run again.
    pub fn supervise(&mut self) -> Result<(), String> {
        let mut failure = None;
        let mut again = Vec::new();
        for (k, m) in self.children.iter_mut().enumerate() {
            let Ok(Some(status)) = m.child.try_wait() else {
                continue;
            };
            let log = self
                .plan
                .as_ref()
                .and_then(|p| p.log_dir.as_ref())
                .map(|d| {
                    format!(
                        " (its log: {})",
                        d.join(format!("{}.log", m.name)).display()
                    )
                })
                .unwrap_or_default();
            if status.code() == Some(REFUSED) {
                failure = Some(format!("environment worker {} was refused{log}", m.name));
            } else if m.restarts >= MAX_RESTARTS {
                failure = Some(format!(
                    "environment worker {} exited {} times, the last with {status}{log}",
                    m.name,
                    m.restarts + 1
                ));
            } else {
                tracing::warn!(
                    "environment worker {} exited ({status}); starting it again{log}",
                    m.name
                );
                again.push(k);
            }
        }
        for k in again {
            let (name, envs) = (self.children[k].name.clone(), self.children[k].envs);
            self.children[k].child = self.spawn(&name, envs, true)?;
            self.children[k].restarts += 1;
        }
        failure.map_or(Ok(()), Err)
    }

    /// The process ids (for tests that kill one).
    pub fn pids(&self) -> Vec<u32> {
        self.children.iter().map(|m| m.child.id()).collect()
    }

    /// Kills every worker.
    pub fn kill_all(&mut self) {
        for m in &mut self.children {
            if matches!(m.child.try_wait(), Ok(None)) {
                let _ = m.child.kill();
            }
            let _ = m.child.wait();
        }
        self.children.clear();
    }
}

fn cannot_start(python: &Path, e: &std::io::Error) -> String {
    jsae_settings::cannot_start_python(python, "the environment workers", e)
}

impl Drop for WorkerProcesses {
    fn drop(&mut self) {
        self.kill_all();
    }
}
