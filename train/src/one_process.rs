//! One-process training: the actor workers, the embedder trainer and the learner each own
//! their state and exchange only messages (transition batches, rollout fragments, weight
//! snapshots, an evaluation report), here handed over in lockstep on one thread, so a seed
//! gives the same run twice.

use std::path::{Path, PathBuf};

use jsae_embedder::EmbedderTrainer;
use jsae_embedder::lifecycle::EmbedderRun;
use jsae_learner::lifecycle::LearnerRun;
use jsae_learner::{Ingested, Learner};
use jsae_record::{Recorder, RecordingInfo};
use jsae_run_dir::{Resume, RunDir, Summary};
use jsae_wire::EmbeddingSnapshot;

use crate::progress::Progress;
use jsae_report::plot;
use jsae_settings::TrainConfig;

use jsae_actor::worker::{ActorWorker, WorkerError};

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// Invalid configuration.
    #[error(transparent)]
    Config(#[from] jsae_settings::ConfigError),
    /// The run directory could not be written.
    #[error("run directory {path}: {source}")]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A component refused a message.
    #[error("learner: {0}")]
    Learner(#[from] jsae_learner::LearnerError),
    /// An embedding or policy snapshot could not be applied.
    #[error("actor: {0}")]
    Worker(#[from] WorkerError),
    /// A service process failed.
    #[error("{0}")]
    Service(String),
    /// The embedder refused a transition batch.
    #[error("embedder: {0}")]
    Embedder(String),
    /// The recording could not be written.
    #[error("--record: {0}")]
    Record(#[from] jsae_record::RecordError),
}

fn io(path: &std::path::Path) -> impl FnOnce(std::io::Error) -> TrainError + '_ {
    move |source| TrainError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What a finished run left behind.
#[derive(Debug, Clone)]
pub struct RunOutcome {
    /// The summary (also in `summary.json`).
    pub summary: Summary,
    /// The run directory.
    pub dir: PathBuf,
    /// Plots written.
    pub plots: Vec<PathBuf>,
}

/// What the command line adds to a run's settings (config.toml does not keep these): the
/// files it records into and pre-trains from, and whether it continues a stopped run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Every stepped transition goes into this MCAP file; with several actors as separate
    /// processes, actor K writes `STEM-actor-K.mcap` beside it ([`RunOptions::actor_record`]).
    pub record: Option<PathBuf>,
    /// The embedder pre-trains on this recording instead of fresh random play.
    pub pretrain_from: Option<PathBuf>,
    /// Continue the stopped run in the run directory (`jsae train --resume`): from its latest
    /// policy and embedding checkpoints, counting on from its last metrics row.
    pub resume: bool,
    /// The token and TLS files the service processes are started with (separate processes
    /// only: in one process nothing travels over the network).
    pub security: jsae_net::security::SecurityFlags,
}

impl RunOptions {
    /// The file actor `id` of `actors` separate processes records into.
    pub fn actor_record(&self, id: usize, actors: usize) -> Option<PathBuf> {
        let path = self.record.as_ref()?;
        if actors <= 1 {
            return Some(path.clone());
        }
        let stem = path.file_stem().unwrap_or_default().to_string_lossy();
        Some(path.with_file_name(format!("{stem}-actor-{id}.mcap")))
    }
}

/// The run's name in recordings: its directory's name.
pub fn run_id(config: &TrainConfig) -> String {
    config
        .out
        .file_name()
        .map_or_else(|| "run".to_string(), |n| n.to_string_lossy().into_owned())
}

/// Trains in this process and writes the run directory.
pub fn train_one_process(
    config: &TrainConfig,
    progress: &mut Progress,
) -> Result<RunOutcome, TrainError> {
    train_one_process_with(config, &RunOptions::default(), progress)
}

/// [`train_one_process`], recording and pre-training from recordings as `files` say. The
/// learner and the embedder open on the run directory as their services do
/// ([`LearnerRun`], [`EmbedderRun`]); only the message passing is this driver's
/// ([`Lockstep`]).
pub fn train_one_process_with(
    config: &TrainConfig,
    files: &RunOptions,
    progress: &mut Progress,
) -> Result<RunOutcome, TrainError> {
    config.validate()?;
    let run = RunDir::new(&config.out);
    let dir = config.out.clone();
    std::fs::create_dir_all(run.checkpoints().path()).map_err(io(&dir))?;
    run.write_config(config).map_err(io(&dir))?;
    let resume = match files.resume {
        true => Resume::Required,
        false => Resume::Never,
    };
    let mut lockstep = Lockstep::open(config, files, resume, progress)?;
    // what a fresh run's policy learns from first, where its settings ask
    let logged = match (resume, &config.init_from) {
        (Resume::Never, None) => {
            crate::logs::logged_purchases(config).map_err(TrainError::Service)?
        }
        _ => None,
    };
    let first = lockstep
        .learner
        .first_snapshot(logged.as_ref(), &mut |line| progress.note(&line))
        .map_err(lifecycle)?;
    let mut recorder = match &files.record {
        Some(path) => {
            let actors = &mut lockstep.actors;
            actors.iter_mut().for_each(|a| a.set_recording(true));
            let (states, actions) = (actors[0].state_space(), actors[0].action_space());
            let info = RecordingInfo::of_run(config, &run_id(config), states, actions);
            Some(Recorder::create(path, &info)?)
        }
        None => None,
    };
    for a in &mut lockstep.actors {
        a.set_policy(&first)?;
    }
    while lockstep.learner.learner().env_steps() < config.env_steps {
        for i in 0..lockstep.actors.len() {
            lockstep.rollout(i, recorder.as_mut(), config, progress)?;
        }
    }
    if let Some(r) = recorder {
        let path = r.path().to_path_buf();
        let n = r.finish()?;
        progress.note(&format!("{n} transitions recorded in {}", path.display()));
    }
    progress.note("evaluating the deterministic and the sampled policy");
    let eval = lockstep.actors[0].evaluate(config.eval_episodes, config.eval_seed());
    let summary = lockstep
        .learner
        .finish(config, &eval, lockstep.last_embedding.as_ref())
        .map_err(lifecycle)?;
    let embedding = lockstep.actors[0].embedding();
    let plots = plot::write_run_plots(&run, config, embedding).map_err(io(&dir))?;
    progress.finish();
    Ok(RunOutcome {
        summary,
        dir,
        plots,
    })
}

/// The run's actor workers ([`actor_worker`] for each id).
fn actor_workers(
    config: &TrainConfig,
) -> Result<(Vec<ActorWorker>, Vec<jsae_remote_envs::Hosting>), TrainError> {
    let mut actors = Vec::new();
    let mut hosting = Vec::new();
    for id in 0..config.actors as u64 {
        let (actor, hosted) = actor_worker(config, id)?;
        actors.push(actor);
        hosting.extend(hosted);
    }
    Ok((actors, hosting))
}

/// Actor `id` of a run in this process: over built-in environments, or over a gym
/// environment's workers, which this process starts and serves (a host on loopback,
/// `environment.gym.workers` workers, at least one, their logs in the run's `logs/`); the
/// hosting lasts as long as it is kept.
pub fn actor_worker(
    config: &TrainConfig,
    id: u64,
) -> Result<(ActorWorker, Option<jsae_remote_envs::Hosting>), TrainError> {
    if config.env != jsae_settings::EnvName::Gym {
        return Ok((ActorWorker::new(config, id, config.device)?, None));
    }
    let plan = jsae_remote_envs::HostPlan {
        listen: "127.0.0.1:0".into(),
        workers: (config.environment.gym.workers as usize).max(1),
        log_dir: Some(RunDir::new(&config.out).logs()),
        name: format!("{id}-"),
        worker_env: Vec::new(),
    };
    let security = jsae_net::security::Security::default();
    let (mut pool, hosted) = jsae_remote_envs::host_on_own_runtime(
        &config.environment.gym,
        config.envs_per_actor,
        &security,
        &plan,
    )
    .map_err(TrainError::Service)?;
    pool.set_max_abs_reward(f64::from(config.ppo.max_abs_reward));
    let actor = ActorWorker::with_pool(config, id, config.device, Box::new(pool));
    Ok((actor, Some(hosted)))
}

fn lifecycle(e: anyhow::Error) -> TrainError {
    TrainError::Service(format!("{e:#}"))
}

/// The actor workers, the embedder and the learner of a one-process run, handing each other
/// their messages in lockstep on one thread.
struct Lockstep {
    actors: Vec<ActorWorker>,
    /// A gym environment's hosts and worker processes, one per actor (kept while the run
    /// lasts).
    _hosting: Vec<jsae_remote_envs::Hosting>,
    learner: LearnerRun,
    embedder: Option<EmbedderRun>,
    /// The newest embedding snapshot (what the learner's metrics and last checkpoint name).
    last_embedding: Option<EmbeddingSnapshot>,
}

impl Lockstep {
    /// The actors, and the learner and embedder opened on the run directory.
    fn open(
        config: &TrainConfig,
        files: &RunOptions,
        resume: Resume,
        progress: &mut Progress,
    ) -> Result<Self, TrainError> {
        let (mut actors, hosting) = actor_workers(config)?;
        // each steps its share of a shared batch, as the learner service would tell it
        for (actor, envs) in actors.iter_mut().zip(config.actor_envs()) {
            actor.set_active_envs(envs);
        }
        let mut note = |line: String| progress.note(&line);
        let learner = LearnerRun::open(config, Learner::for_run(config), resume, &mut note)
            .map_err(lifecycle)?;
        let mut lockstep = Self {
            actors,
            _hosting: hosting,
            learner,
            embedder: None,
            last_embedding: None,
        };
        if config.algo.representation().needs_embedder() {
            let (states, actions) = (
                lockstep.actors[0].state_space().clone(),
                lockstep.actors[0].action_space().clone(),
            );
            let mut trainer = EmbedderTrainer::for_run(config, &states, &actions);
            if let Some(logged) = crate::logs::logged_items(config).map_err(TrainError::Service)? {
                trainer
                    .set_logged(std::sync::Arc::new(logged))
                    .map_err(TrainError::Embedder)?;
            }
            let phases = progress.phases();
            trainer.observe_pretraining(move |p| phases.report(None, &p.to_string()));
            let (opened, first) = EmbedderRun::open(
                config,
                trainer,
                Some(RunDir::new(&config.out).checkpoints().path()),
                resume,
                files.pretrain_from.as_deref(),
                &mut |line| progress.note(&line),
            )
            .map_err(TrainError::Embedder)?;
            lockstep.embedder = Some(opened);
            if let Some(first) = first {
                lockstep.new_embedding(first)?;
            }
        }
        Ok(lockstep)
    }

    /// Hands a snapshot of the embedder's to every actor.
    fn new_embedding(&mut self, snap: EmbeddingSnapshot) -> Result<(), TrainError> {
        for a in &mut self.actors {
            a.set_embedding(&snap)?;
        }
        self.last_embedding = Some(snap);
        Ok(())
    }

    /// Actor `i`'s rollout: its transitions to the recording and the embedder, its fragments
    /// to the learner, and each resulting snapshot back to every actor.
    fn rollout(
        &mut self,
        i: usize,
        recorder: Option<&mut Recorder>,
        config: &TrainConfig,
        progress: &mut Progress,
    ) -> Result<(), TrainError> {
        let rollout = self.actors[i].collect(config.rollout_len);
        if let Some(reason) = self.actors[i].env_failure() {
            return Err(TrainError::Service(format!(
                "actor {i}'s environments: {reason}"
            )));
        }
        if let (Some(r), Some(steps)) = (recorder, &rollout.recorded) {
            r.write(&rollout.transitions, steps)?;
        }
        let env_steps = self.learner.learner().env_steps();
        if let Some(emb) = self.embedder.as_mut()
            && let Some(snap) = embedder_step(
                emb,
                &rollout.transitions,
                env_steps,
                &self.actors,
                config,
                progress,
            )?
        {
            self.new_embedding(snap)?;
        }
        let actor = &self.actors[i];
        self.learner.learner_mut().observe_actor_steps(
            actor.id(),
            actor.incarnation(),
            actor.env_steps(),
        );
        for fragment in rollout.fragments {
            if let Ingested::Updated(report) = self.learner.learner_mut().ingest(fragment)? {
                self.learner
                    .record_update(&report, self.last_embedding.as_ref())
                    .map_err(lifecycle)?;
                progress.update(&report.metrics);
                for a in &mut self.actors {
                    a.set_policy(&report.snapshot)?;
                }
            }
        }
        Ok(())
    }
}

/// Hands a rollout's transitions to the embedder as its service would receive them; returns
/// the snapshot it published after them (checkpointed), if any.
fn embedder_step(
    emb: &mut EmbedderRun,
    transitions: &jsae_wire::TransitionBatch,
    learner_steps: u64,
    actors: &[ActorWorker],
    config: &TrainConfig,
    progress: &mut Progress,
) -> Result<Option<EmbeddingSnapshot>, TrainError> {
    let trainer = emb.trainer_mut();
    trainer
        .ingest(transitions)
        .map_err(|e| TrainError::Embedder(e.to_string()))?;
    if !trainer.pretrained() {
        let steps = actors.iter().map(ActorWorker::env_steps).sum::<u64>();
        progress.phase(
            Some(learner_steps.max(steps)),
            &format!(
                "random play for pre-training: {}/{} transitions",
                trainer.replay_len().min(trainer.pretrain_budget()),
                trainer.pretrain_budget()
            ),
        );
    }
    if !trainer.held() && config.embedding_held_at(learner_steps) {
        // embedding.hold_from: the policy's last updates use one embedding
        trainer.hold();
    }
    let Some(snap) = trainer
        .poll()
        .map_err(|e| TrainError::Embedder(e.to_string()))?
    else {
        return Ok(None);
    };
    if snap.version == 1 {
        progress.note(&format!(
            "embedding pre-trained on {} random transitions (model loss {:.4})",
            trainer.replay_len(),
            snap.model_loss
        ));
    }
    // the latest weights, so that a stopped run can be resumed
    emb.checkpoint(&snap).map_err(io(Path::new(&config.out)))?;
    Ok(Some(snap))
}
