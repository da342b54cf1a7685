//! `jsae train` with the services as separate processes on loopback: this executable is
//! started again as `jsae embedder`, `jsae learner` and `jsae actor` (the same code as the
//! `jsae-embedder`, `jsae-learner` and `jsae-actor` binaries), each on a free port it reports
//! on stdout. The learner ends the run; then the embedder is stopped with SIGTERM (it writes
//! its final checkpoint), the plots are drawn from the run directory and the summary read
//! back. Each process's output goes to `DIR/logs/`. If anything fails, every child is killed;
//! SIGTERM or SIGINT to `jsae train` is passed on to every child (SIGTERM, then SIGKILL for
//! one that does not stop), so none is left running under PID 1.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Duration;

use jsae_net::security::SecurityFlags;
use jsae_run_dir::RunDir;
use jsae_run_dir::{MetricsTable, Summary};
use jsae_settings::TrainConfig;

use crate::log_echo::LogEcho;
use crate::one_process::{RunOptions, RunOutcome, TrainError, run_id};
use crate::progress::Progress;
use jsae_report::plot;

/// A child process, killed if still running when dropped.
#[derive(Debug)]
struct Service {
    name: String,
    child: Child,
}

impl Drop for Service {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// How every service process is started: this executable, the run directory its log goes
/// to, and the security settings it is handed (as `JSAE_*` variables, absolute paths) with
/// the URL scheme they imply.
struct Children<'a> {
    exe: &'a Path,
    run: &'a RunDir,
    security: Vec<(&'static str, PathBuf)>,
    scheme: &'static str,
}

impl Service {
    /// Starts `exe args..`, its stderr and the rest of its stdout into `logs/NAME.log`; waits
    /// for the first stdout line when `listens` and returns the URL of the address it names.
    fn start(
        children: &Children<'_>,
        args: &[String],
        name: &str,
        listens: bool,
    ) -> Result<(Self, Option<String>), TrainError> {
        let log_path = children.run.log(name);
        let log = std::fs::File::create(&log_path).map_err(|source| TrainError::Io {
            path: log_path.clone(),
            source,
        })?;
        let err_log = log.try_clone().map_err(|source| TrainError::Io {
            path: log_path.clone(),
            source,
        })?;
        let typed: Vec<String> = std::env::args().collect();
        let mut child = Command::new(children.exe)
            .args(args)
            .envs(children.security.iter().map(|(k, v)| (k, v)))
            .env(
                jsae_run_dir::COMMAND_LINE_ENV,
                serde_json::to_string(&typed).unwrap_or_default(),
            )
            // one address for three processes cannot work: metrics only by hand or in
            // containers (docs/src/operations/prometheus.md)
            .env_remove("JSAE_METRICS_LISTEN")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(err_log)
            .spawn()
            .map_err(|e| TrainError::Service(format!("cannot start {name}: {e}")))?;
        let stdout = child.stdout.take();
        let (tx, rx) = mpsc::channel();
        let mut log = log;
        std::thread::spawn(move || {
            let Some(out) = stdout else { return };
            let mut first = true;
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if first {
                    let _ = tx.send(line.clone());
                    first = false;
                }
                let _ = writeln!(log, "{line}");
            }
        });
        let service = Self {
            name: name.to_string(),
            child,
        };
        if !listens {
            return Ok((service, None));
        }
        let line = rx.recv_timeout(Duration::from_secs(60)).map_err(|_| {
            TrainError::Service(format!(
                "{name} did not report its address (see {})",
                log_path.display()
            ))
        })?;
        let addr = jsae_net::logging::announced_address(&line)
            .ok_or_else(|| TrainError::Service(format!("{name} said {line:?}")))?;
        Ok((service, Some(format!("{}://{addr}", children.scheme))))
    }

    fn terminate(&mut self, timeout: Duration) {
        if !jsae_experiments::child::terminate(&mut self.child, timeout) {
            tracing::warn!("{} did not stop in {timeout:?}; killed it", self.name);
        }
    }
}

fn common_args(config: &TrainConfig, config_path: &Path) -> Vec<String> {
    let format = jsae_net::logging::chosen_log_format();
    let log_format = format.map(|f| ["--log-format".to_string(), f.as_str().to_string()]);
    log_format
        .into_iter()
        .flatten()
        .chain([
            "--env".into(),
            config.env.as_str().into(),
            "--algo".into(),
            config.algo.as_str().into(),
            "--seed".into(),
            config.seed.to_string(),
            "--config".into(),
            config_path.display().to_string(),
        ])
        .collect()
}

/// Checks the security flags for services that are each other's clients on 127.0.0.1 (a
/// server with a TLS identity needs clients with a CA, and the other way round); the URL
/// scheme they give.
pub fn check_security(flags: &SecurityFlags) -> Result<&'static str, TrainError> {
    let security = flags.load().map_err(TrainError::Service)?;
    if flags.tls_cert.is_some() != flags.tls_ca.is_some() {
        return Err(TrainError::Service(
            "with separate processes the services are each other's clients: --tls-cert and \
             --tls-key need --tls-ca (and the other way round); the certificate must name \
             127.0.0.1"
                .into(),
        ));
    }
    Ok(security.scheme())
}

/// A flag that SIGTERM or SIGINT to this process sets (instead of ending it at once).
fn stop_on_signal() -> Result<Arc<AtomicBool>, TrainError> {
    jsae_experiments::child::stop_on_signal()
        .map_err(|e| TrainError::Service(format!("cannot catch SIGTERM and SIGINT: {e}")))
}

/// A service that exited before the run's end, with the reason its log ends on (the last
/// ERROR line, or the line its `main` printed), so that `jsae train` says why, not only
/// where to look.
fn exited(run: &RunDir, name: &str, status: std::process::ExitStatus) -> TrainError {
    let log = run.log(name);
    let text = std::fs::read_to_string(&log).unwrap_or_default();
    let reason = text
        .lines()
        .rev()
        .find(|l| l.contains("ERROR") || l.starts_with("jsae-") || l.starts_with("jsae "))
        .map(|l| format!(": {}", l.trim()))
        .unwrap_or_default();
    TrainError::Service(format!(
        "the {name} exited ({status}){reason}; see {}",
        log.display()
    ))
}

/// The last data row of `metrics.csv`: (env steps, return, success rate).
fn last_metrics(path: &Path) -> Option<(u64, Option<f64>, Option<f64>)> {
    let table = MetricsTable::read(path).ok()?;
    let last = |name: &str| table.column(name).last().copied().flatten();
    Some((
        last("env_steps")? as u64,
        last("return_mean"),
        last("success_rate"),
    ))
}

/// The embedder's newest pre-training report in its log (text or JSON lines), such as
/// "pre-training the embedding on 32768 transitions: epoch 12/60, about 21 s left".
fn pretraining_phase(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    let phase = jsae_embedder::PRETRAIN_PHASE;
    let line = text.lines().rev().find(|l| l.contains(phase))?;
    let from = &line[line.find(phase)?..];
    Some(
        from.split('"')
            .next()
            .unwrap_or(from)
            .trim_end()
            .to_string(),
    )
}

/// Trains with the embedder, the learner and `config.actors` actors as separate processes
/// of `exe` (this program) and writes the run directory.
pub fn train_processes(
    config: &TrainConfig,
    files: &RunOptions,
    exe: &Path,
    progress: &mut Progress,
) -> Result<RunOutcome, TrainError> {
    config.validate()?;
    let stop = stop_on_signal()?;
    let run = RunDir::new(&config.out);
    let dir = config.out.clone();
    let logs = run.logs();
    std::fs::create_dir_all(&logs).map_err(io(&logs))?;
    let ckpt = run.checkpoints();
    std::fs::create_dir_all(ckpt.path()).map_err(io(&dir))?;
    if !files.resume {
        // a fresh run: a previous run's checkpoint would make the learner resume
        ckpt.clear_latest();
    }
    let config_path = std::path::absolute(run.config_toml()).map_err(io(&dir))?;
    run.write_config(config).map_err(io(&config_path))?;
    let children = Children {
        exe,
        run: &run,
        security: files.security.to_env(),
        scheme: check_security(&files.security)?,
    };
    let mut services = Services::start(&children, config, files, &config_path, progress)?;
    let status = services.watch(&run, config.actors, &stop, progress)?;
    if !status.success() {
        return Err(exited(&run, "learner", status));
    }
    services.stop(Duration::from_secs(10));
    let text = std::fs::read_to_string(run.summary_json()).map_err(io(&dir))?;
    let summary: Summary = serde_json::from_str(&text)
        .map_err(|e| TrainError::Service(format!("summary.json: {e}")))?;
    let plots = plot::plot_run_dir(&run, config).map_err(io(&dir))?;
    progress.finish();
    Ok(RunOutcome {
        summary,
        dir: dir.clone(),
        plots,
    })
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> TrainError + use<> {
    let path = path.to_path_buf();
    move |source| TrainError::Io { path, source }
}

/// An absolute path as an argument.
fn absolute(path: &Path) -> Result<String, TrainError> {
    Ok(std::path::absolute(path)
        .map_err(io(path))?
        .display()
        .to_string())
}

/// The service processes of one run.
struct Services {
    embedder: Option<Service>,
    learner: Service,
    actors: Vec<Service>,
}

impl Services {
    /// Starts the embedder (where the algorithm needs one), then the learner, then the
    /// actors, each told the addresses of those before it.
    fn start(
        children: &Children<'_>,
        config: &TrainConfig,
        files: &RunOptions,
        config_path: &Path,
        progress: &mut Progress,
    ) -> Result<Self, TrainError> {
        let common = common_args(config, config_path);
        let listen = ["--listen".to_string(), "127.0.0.1:0".to_string()];
        let (mut embedder, mut embedder_url) = (None, None);
        if config.algo.representation().needs_embedder() {
            let mut args = vec!["embedder".to_string()];
            args.extend(listen.iter().chain(&common).cloned());
            let checkpoints = absolute(children.run.checkpoints().path())?;
            args.extend(["--checkpoint-dir".into(), checkpoints]);
            if let Some(path) = &files.pretrain_from {
                args.extend(["--pretrain-from".into(), path.display().to_string()]);
            }
            let (service, url) = Service::start(children, &args, "embedder", true)?;
            progress.note(&format!("embedder on {}", url.as_deref().unwrap_or("?")));
            (embedder, embedder_url) = (Some(service), url);
        }
        let mut args = vec!["learner".to_string()];
        args.extend(listen.iter().chain(&common).cloned());
        args.extend(["--env-steps".into(), config.env_steps.to_string()]);
        args.extend(["--out".into(), absolute(&config.out)?]);
        if let Some(url) = &embedder_url {
            args.extend(["--embedder".into(), url.clone()]);
        }
        if files.resume {
            args.push("--resume".into());
        }
        let (learner, learner_url) = Service::start(children, &args, "learner", true)?;
        let learner_url = learner_url.unwrap_or_default();
        progress.note(&format!("learner on {learner_url}"));
        let mut actors = Vec::new();
        for id in 0..config.actors {
            let mut args = vec!["actor".to_string(), "--learner".into(), learner_url.clone()];
            args.extend(common.iter().cloned());
            args.extend(["--id".into(), id.to_string()]);
            args.extend(["--envs".into(), config.envs_per_actor.to_string()]);
            if let Some(url) = &embedder_url {
                args.extend(["--embedder".into(), url.clone()]);
            }
            if let Some(path) = files.actor_record(id, config.actors) {
                args.extend(["--record".into(), path.display().to_string()]);
                args.extend(["--run-id".into(), run_id(config)]);
            }
            if config.env == jsae_settings::EnvName::Gym {
                // it starts its environment workers itself, their logs beside its own
                args.extend(["--worker-logs".into(), absolute(&children.run.logs())?]);
            }
            let name = format!("actor-{id}");
            actors.push(Service::start(children, &args, &name, false)?.0);
        }
        Ok(Self {
            embedder,
            learner,
            actors,
        })
    }

    /// Stops the actors (each given `actors` to stop), the learner and the embedder.
    fn stop(&mut self, actors: Duration) {
        for a in &mut self.actors {
            a.terminate(actors);
        }
        if self.learner.child.try_wait().ok().flatten().is_none() {
            self.learner.terminate(Duration::from_secs(30));
        }
        if let Some(e) = self.embedder.as_mut() {
            e.terminate(Duration::from_secs(30));
        }
    }

    /// Shows the services' warnings and the run's progress until the learner exits (its
    /// status); stops them all on a signal, when the embedder exits, or when every actor
    /// failed.
    fn watch(
        &mut self,
        run: &RunDir,
        actors: usize,
        stop: &AtomicBool,
        progress: &mut Progress,
    ) -> Result<std::process::ExitStatus, TrainError> {
        let metrics = run.metrics_csv();
        let mut echoes: Vec<LogEcho> = self
            .embedder
            .iter()
            .map(|_| "embedder".to_string())
            .chain(["learner".to_string()])
            .chain((0..actors).map(|id| format!("actor-{id}")))
            .map(|name| LogEcho::new(&name, run.log(&name)))
            .collect();
        loop {
            for echo in &mut echoes {
                echo.show_new(progress);
            }
            if let Ok(Some(status)) = self.learner.child.try_wait() {
                return Ok(status);
            }
            if stop.load(Ordering::Relaxed) {
                progress.note("stopping: signal received; stopping the services");
                self.stop(Duration::from_secs(10));
                return Err(TrainError::Service(format!(
                    "stopped by a signal; the services stopped, their checkpoints are in {}",
                    run.checkpoints().path().display()
                )));
            }
            if let Some(e) = self.embedder.as_mut()
                && let Ok(Some(status)) = e.child.try_wait()
            {
                return Err(exited(run, "embedder", status));
            }
            // every actor failed: nothing will step again (an actor that dies beside others
            // is the run's to survive; one that exits 0 was told the run is over)
            let statuses: Vec<_> = (self.actors.iter_mut())
                .map(|a| a.child.try_wait().ok().flatten())
                .collect();
            if statuses.iter().all(|s| s.is_some_and(|s| !s.success()))
                && let Some(Some(status)) = statuses.first()
            {
                self.stop(Duration::from_secs(1));
                return Err(exited(run, "actor-0", *status));
            }
            match last_metrics(&metrics) {
                Some((steps, ret, success)) => progress.position(steps, ret, success),
                None if self.embedder.is_some() => progress.phase(
                    None,
                    &pretraining_phase(&run.log("embedder")).unwrap_or_else(|| {
                        "waiting for the embedder: random play, then pre-training".into()
                    }),
                ),
                None => {}
            }
            std::thread::sleep(Duration::from_millis(500));
        }
    }
}

/// This program's path, to start the services from.
pub fn current_exe() -> Result<PathBuf, TrainError> {
    std::env::current_exe().map_err(|e| TrainError::Service(format!("cannot find myself: {e}")))
}
