//! One-process training: the actor workers, the embedder trainer and the learner each own
//! their state and exchange only messages (transition batches, rollout fragments, weight
//! snapshots, an evaluation report), here handed over in lockstep on one thread, so a seed
//! gives the same run twice.

use std::path::PathBuf;
use std::time::Instant;

use jsae_embedder::{EmbedderTrainer, pretrain_from_recording};
use jsae_learner::{Ingested, Learner, UPDATE_COLUMNS, update_scalars};
use jsae_record::{Recorder, RecordingInfo};
use jsae_run_dir::{
    LatestCheckpoint, MetricsSink, ResumePoint, RunDir, RunMetrics, Summary, Weights,
};
use jsae_wire::{EmbeddingSnapshot, PolicySnapshot};

use crate::plot;
use crate::progress::Progress;
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

/// [`train_one_process`], recording and pre-training from recordings as `files` say.
pub fn train_one_process_with(
    config: &TrainConfig,
    files: &RunOptions,
    progress: &mut Progress,
) -> Result<RunOutcome, TrainError> {
    config.validate()?;
    let run = RunDir::new(&config.out);
    let dir = config.out.clone();
    let ckpt = run.checkpoints();
    std::fs::create_dir_all(ckpt.path()).map_err(io(&dir))?;
    std::fs::write(run.config_toml(), config.to_toml()).map_err(io(&dir))?;
    let resume = match files.resume {
        true => Some(ResumePoint::of(&run).map_err(io(&dir))?),
        false => None,
    };
    let mut started = resume.map_or_else(Instant::now, |p| p.started());

    let mut actors: Vec<ActorWorker> = (0..config.actors as u64)
        .map(|id| ActorWorker::new(config, id, config.device))
        .collect::<Result<_, _>>()?;
    // each steps its share of a shared batch, as the learner service would tell it
    for (actor, envs) in actors.iter_mut().zip(config.actor_envs()) {
        actor.set_active_envs(envs);
    }
    let (states, actions) = (
        actors[0].state_space().clone(),
        actors[0].action_space().clone(),
    );
    let mut learner = Learner::for_run(config);
    let mut embedder = config.algo.representation().needs_embedder().then(|| {
        EmbedderTrainer::new(
            config.embedding.clone(),
            config.algo.representation(),
            &states,
            &actions,
            config.seed,
            config.device,
        )
        .with_action_motions(config.env.action_motions(&config.environment))
    });
    if let Some(emb) = embedder.as_mut() {
        let phases = progress.phases();
        emb.observe_pretraining(move |p| phases.report(None, &p.to_string()));
    }
    let mut last_embedding: Option<EmbeddingSnapshot> = None;
    if let Some(point) = resume {
        let policy = ckpt
            .read_latest_checkpoint(Weights::Policy)
            .ok_or_else(|| {
                TrainError::Service(format!(
                    "--resume: no policy checkpoint in {}",
                    ckpt.path().display()
                ))
            })?;
        let wall = learner
            .resume(&policy)
            .map_err(|e| TrainError::Service(format!("--resume policy: {e}")))?;
        // the checkpoint's env steps and wall time, else the last metrics row's
        match wall {
            Some(wall) => started = jsae_run_dir::run_started(wall),
            None => learner.count_steps_from(point.env_steps),
        }
        if let Some(emb) = embedder.as_mut() {
            let saved =
                jsae_embedder::service::latest_checkpoint(ckpt.path()).ok_or_else(|| {
                    TrainError::Service(format!(
                        "--resume: no embedding checkpoint in {}",
                        ckpt.path().display()
                    ))
                })?;
            emb.restore(&saved)
                .map_err(|e| TrainError::Embedder(format!("--resume: {e}")))?;
            for a in &mut actors {
                a.set_embedding(&saved)?;
            }
            last_embedding = Some(saved);
        }
        progress.note(&format!(
            "resuming at {} env steps from policy version {}",
            point.env_steps,
            learner.version()
        ));
    } else if let Some(source) = jsae_run_dir::init_source(config)? {
        learner
            .warm_start(&source.policy)
            .map_err(|e| TrainError::Service(format!("--init-from policy: {e}")))?;
        if let Some(emb) = embedder.as_mut() {
            let parts = emb.warm_start(&source).map_err(TrainError::Embedder)?;
            progress.note(&format!(
                "warm start from {}: the policy and embedding parts {}",
                source.dir.display(),
                parts.join(", ")
            ));
        }
    }
    // rows of updates past the checkpoint's (a forged row, or a row of an update whose
    // checkpoint was lost) are cut, so the rows this run writes are not taken for repeats
    let mut metrics = RunMetrics::open(&run, &UPDATE_COLUMNS, resume.map(|_| learner.updates()))
        .map_err(io(&dir))?;

    if config.init_from.is_none() && resume.is_none() {
        let logged = jsae_recommender::logged_purchases(config).map_err(TrainError::Service)?;
        for note in learner.learn_from_logs(logged.as_ref())? {
            progress.note(&note);
        }
    }
    if let (Some(path), Some(emb), None) = (&files.pretrain_from, embedder.as_mut(), resume) {
        let done = pretrain_from_recording(emb, path).map_err(TrainError::Embedder)?;
        progress.note(&done.note);
        let snap = &done.snapshot;
        ckpt.write_latest(Weights::Embedding, snap.version, &snap.bytes)
            .map_err(io(ckpt.path()))?;
        for a in &mut actors {
            a.set_embedding(&done.snapshot)?;
        }
        last_embedding = Some(done.snapshot);
    }
    let mut recorder = match &files.record {
        Some(path) => {
            actors.iter_mut().for_each(|a| a.set_recording(true));
            let info = RecordingInfo::of_run(config, &run_id(config), &states, &actions);
            Some(Recorder::create(path, &info)?)
        }
        None => None,
    };
    let first = learner
        .snapshot()
        .map_err(jsae_learner::LearnerError::from)?;
    for a in &mut actors {
        a.set_policy(&first)?;
    }
    // the latest policy from the start (as the learner service does), so a run stopped
    // before its first update resumes too; with the training state, as every checkpoint
    let checkpoint = |learner: &Learner, snap: &PolicySnapshot, wall: f64| {
        Ok::<_, TrainError>(LatestCheckpoint {
            version: snap.version,
            weights: snap.bytes.clone(),
            state: learner.training_state(wall)?,
        })
    };
    let saved = checkpoint(&learner, &first, started.elapsed().as_secs_f64())?;
    ckpt.write_latest_checkpoint(Weights::Policy, &saved)
        .map_err(io(ckpt.path()))?;
    let mut last_policy: PolicySnapshot = first;
    while learner.env_steps() < config.env_steps {
        for i in 0..actors.len() {
            let rollout = actors[i].collect(config.rollout_len);
            if let (Some(r), Some(steps)) = (recorder.as_mut(), &rollout.recorded) {
                r.write(&rollout.transitions, steps)?;
            }
            if let Some(emb) = embedder.as_mut() {
                emb.ingest(&rollout.transitions)
                    .map_err(|e| TrainError::Embedder(e.to_string()))?;
                if !emb.pretrained() {
                    let steps = actors.iter().map(ActorWorker::env_steps).sum::<u64>();
                    progress.phase(
                        Some(learner.env_steps().max(steps)),
                        &format!(
                            "random play for pre-training: {}/{} transitions",
                            emb.replay_len().min(emb.pretrain_budget()),
                            emb.pretrain_budget()
                        ),
                    );
                }
                if !emb.held() && config.embedding_held_at(learner.env_steps()) {
                    // embedding.hold_from: the policy's last updates use one embedding
                    emb.hold();
                }
                if let Some(snap) = emb
                    .poll()
                    .map_err(|e| TrainError::Embedder(e.to_string()))?
                {
                    if snap.version == 1 {
                        progress.note(&format!(
                            "embedding pre-trained on {} random transitions (model loss {:.4})",
                            emb.replay_len(),
                            snap.model_loss
                        ));
                    }
                    for a in &mut actors {
                        a.set_embedding(&snap)?;
                    }
                    // the latest weights, so that a stopped run can be resumed
                    ckpt.write_latest(Weights::Embedding, snap.version, &snap.bytes)
                        .map_err(io(ckpt.path()))?;
                    last_embedding = Some(snap);
                }
            }
            learner.observe_actor_steps(
                actors[i].id(),
                actors[i].incarnation(),
                actors[i].env_steps(),
            );
            for fragment in rollout.fragments {
                if let Ingested::Updated(report) = learner.ingest(fragment)? {
                    // the checkpoint before the row: a stop between them leaves a row
                    // missing, never the same update twice
                    let wall = started.elapsed().as_secs_f64();
                    let saved = checkpoint(&learner, &report.snapshot, wall)?;
                    ckpt.write_latest_checkpoint(Weights::Policy, &saved)
                        .map_err(io(ckpt.path()))?;
                    let row = update_scalars(&report.metrics, wall, last_embedding.as_ref());
                    metrics.record(&row).map_err(io(&run.metrics_csv()))?;
                    progress.update(&report.metrics);
                    for a in &mut actors {
                        a.set_policy(&report.snapshot)?;
                    }
                    last_policy = report.snapshot;
                }
            }
        }
    }

    if let Some(r) = recorder {
        let path = r.path().to_path_buf();
        let n = r.finish()?;
        progress.note(&format!("{n} transitions recorded in {}", path.display()));
    }
    progress.note("evaluating the deterministic and the sampled policy");
    let eval = actors[0].evaluate(config.eval_episodes, config.eval_seed());
    let wall = started.elapsed().as_secs_f64();
    let summary = learner.summary(config, learner.env_steps(), wall, &eval);
    ckpt.write_versioned(Weights::Policy, last_policy.version, &last_policy.bytes)
        .map_err(io(ckpt.path()))?;
    if let Some(e) = &last_embedding {
        ckpt.write_versioned(Weights::Embedding, e.version, &e.bytes)
            .map_err(io(ckpt.path()))?;
    }
    summary.write(&run).map_err(io(&dir))?;
    metrics
        .record_eval(summary.env_steps, &summary.eval_scalars())
        .map_err(io(&run.tensorboard()))?;
    let plots = plot::write_run_plots(&run, config, actors[0].embedding()).map_err(io(&dir))?;
    progress.finish();
    Ok(RunOutcome {
        summary,
        dir,
        plots,
    })
}
