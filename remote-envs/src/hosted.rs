//! A pool of remote environments with its host served and its workers started by this
//! process: what an actor does, and what a one-process run or `jsae eval` does without
//! an actor process (the host then runs on a small runtime of its own).

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use jsae_envs::GymConfig;
use jsae_net::security::Security;

use crate::pool::RemotePool;
use crate::workers::{WorkerPlan, WorkerProcesses};

/// Where the host listens and who starts its workers.
#[derive(Debug, Clone)]
pub struct HostPlan {
    /// The address to listen on (`host:port`, port 0: any free one).
    pub listen: String,
    /// Worker processes to start (0: none; workers connect by hand).
    pub workers: usize,
    /// Where their logs go (None: this process's output).
    pub log_dir: Option<PathBuf>,
    /// Added to the workers' names (e.g. the actor's id).
    pub name: String,
    /// Variables the workers get: the token and CA files the services take
    /// (`SecurityFlags::to_env`), where this process was given them as flags.
    pub worker_env: Vec<(&'static str, PathBuf)>,
}

/// A served host and its started workers: dropping it kills the workers and stops serving.
#[derive(Debug)]
pub struct Hosting {
    /// The host's address, `http://host:port` (`https` with TLS).
    pub url: String,
    /// The address it listens on.
    pub addr: std::net::SocketAddr,
    /// The started workers (the pool starts again one that exits).
    pub workers: Arc<Mutex<WorkerProcesses>>,
    runtime: Option<tokio::runtime::Runtime>,
}

impl Drop for Hosting {
    fn drop(&mut self) {
        // the workers first (killed), then the host's runtime
        self.workers
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .kill_all();
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

/// A pool of `envs` environments of `gym`, its host served on `plan.listen` on a runtime of
/// its own, and `plan.workers` workers started for it.
pub fn host_on_own_runtime(
    gym: &GymConfig,
    envs: usize,
    security: &Security,
    plan: &HostPlan,
) -> Result<(RemotePool, Hosting), String> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("jsae-env-host")
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the environment host's runtime: {e}"))?;
    let (pool, mut hosting) = runtime.block_on(host(gym, envs, security, plan))?;
    hosting.runtime = Some(runtime);
    Ok((pool, hosting))
}

/// As [`host_on_own_runtime`], serving on the caller's runtime (call it within one).
pub async fn host(
    gym: &GymConfig,
    envs: usize,
    security: &Security,
    plan: &HostPlan,
) -> Result<(RemotePool, Hosting), String> {
    let spaces = match (&gym.observation, &gym.action) {
        (Some(o), Some(a)) => (o.clone(), a.clone()),
        _ => return Err(gym.spaces().map(|_| ()).err().unwrap_or_default()),
    };
    let (mut pool, service) = RemotePool::new(&gym.id, spaces, envs)?;
    let listener = jsae_net::bind(&plan.listen).await.map_err(|e| {
        format!(
            "cannot listen on {} for environment workers: {e}",
            plan.listen
        )
    })?;
    let addr = listener
        .local_addr()
        .map_err(|e| format!("the environment host's address: {e}"))?;
    let scheme = if security.serves_tls() {
        "https"
    } else {
        "http"
    };
    let security = security.clone();
    tokio::spawn(async move {
        let served = jsae_net::serve(
            service.server(),
            listener,
            &security,
            None,
            std::future::pending::<()>(),
        )
        .await;
        if let Err(e) = served {
            tracing::error!("the environment host stopped: {e}");
        }
    });
    let url = format!("{scheme}://{addr}");
    let workers = match plan.workers {
        0 => WorkerProcesses::default(),
        n => WorkerProcesses::start(&WorkerPlan {
            env_id: gym.id.clone(),
            url: url.clone(),
            envs,
            workers: n,
            log_dir: plan.log_dir.clone(),
            name: plan.name.clone(),
            max_steps: gym.max_steps,
            env: plan.worker_env.clone(),
        })?,
    };
    let workers = Arc::new(Mutex::new(workers));
    pool.supervise(workers.clone());
    Ok((
        pool,
        Hosting {
            url,
            addr,
            workers,
            runtime: None,
        },
    ))
}
