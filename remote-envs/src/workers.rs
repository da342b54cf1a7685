//! Worker processes an actor starts itself: `PYTHON -m jsae.envs --env ID --actor URL
//! --envs N` for each ([`jsae_settings::python`]), their output in a log file, killed when
//! the guard is dropped.

use std::path::{Path, PathBuf};

use jsae_settings::python;
use std::process::{Child, Command, Stdio};

/// Worker processes, killed on drop.
#[derive(Debug, Default)]
pub struct WorkerProcesses {
    children: Vec<(String, Child)>,
}

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
}

impl WorkerProcesses {
    /// Starts the workers of `plan`.
    pub fn start(plan: &WorkerPlan) -> Result<Self, String> {
        let python = python();
        let workers = plan.workers.clamp(1, plan.envs.max(1));
        let mut started = Self::default();
        for k in 0..workers {
            // the environments shared as evenly as they go, the first ones taking the rest
            let envs = plan.envs / workers + usize::from(k < plan.envs % workers);
            let name = format!("worker-{}{k}", plan.name);
            let (out, err) = match &plan.log_dir {
                Some(dir) => {
                    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
                    let path = dir.join(format!("{name}.log"));
                    let file = std::fs::File::create(&path)
                        .map_err(|e| format!("{}: {e}", path.display()))?;
                    let err = file
                        .try_clone()
                        .map_err(|e| format!("{}: {e}", path.display()))?;
                    (Stdio::from(file), Stdio::from(err))
                }
                None => (Stdio::inherit(), Stdio::inherit()),
            };
            let child = Command::new(&python)
                .args([
                    "-m",
                    "jsae.envs",
                    "--env",
                    &plan.env_id,
                    "--actor",
                    &plan.url,
                ])
                .args(["--envs", &envs.to_string(), "--name", &name])
                .stdin(Stdio::null())
                .stdout(out)
                .stderr(err)
                .spawn()
                .map_err(|e| cannot_start(&python, &e))?;
            started.children.push((name, child));
        }
        Ok(started)
    }

    /// The process ids (for tests that kill one).
    pub fn pids(&self) -> Vec<u32> {
        self.children.iter().map(|(_, c)| c.id()).collect()
    }
}

fn cannot_start(python: &Path, e: &std::io::Error) -> String {
    jsae_settings::cannot_start_python(python, "the environment workers", e)
}

impl Drop for WorkerProcesses {
    fn drop(&mut self) {
        for (_, child) in &mut self.children {
            if matches!(child.try_wait(), Ok(None)) {
                let _ = child.kill();
            }
            let _ = child.wait();
        }
    }
}
