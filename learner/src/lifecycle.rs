//! The learner's side of a run directory, in one place for the learner service and the
//! one-process driver: opening it (resume from the latest policy checkpoint, else a warm
//! start from `--init-from`, else fresh), the first snapshot (after a fresh run's policy has
//! learned from logged purchases where the settings ask), the checkpoint with the training
//! state before each snapshot goes out and the metrics row after it, and the end of the run
//! (summary.json, the last versioned checkpoints, the evaluation's scalars).

use std::time::Instant;

use anyhow::Context;
use jsae_run_dir::{
    LatestCheckpoint, MetricsSink, Resume, ResumePoint, RunDir, RunMetrics, Summary, Weights,
};
use jsae_settings::TrainConfig;
use jsae_wire::{EmbeddingSnapshot, EvalReport, PolicySnapshot};

use crate::{Learner, LoggedPurchases, UPDATE_COLUMNS, UpdateReport, update_scalars};

/// A learner opened on its run directory.
#[derive(Debug)]
pub struct LearnerRun {
    learner: Learner,
    dir: RunDir,
    metrics: RunMetrics,
    started: Instant,
    /// Neither resumed nor warm-started: the policy learns from logged purchases (where the
    /// settings ask) before its first snapshot.
    fresh: bool,
}

impl LearnerRun {
    /// Opens `config.out` for `learner` (built for `config`): resumes, warm-starts or starts
    /// fresh as `resume` and `config.init_from` say; writes config.toml unless it resumed;
    /// opens metrics.csv and the TensorBoard events. What it did goes to `note`.
    ///
    /// # Errors
    /// A checkpoint that does not load, none where one is required, or files that cannot be
    /// read or written.
    pub fn open(
        config: &TrainConfig,
        mut learner: Learner,
        resume: Resume,
        note: &mut dyn FnMut(String),
    ) -> anyhow::Result<Self> {
        let dir = RunDir::new(&config.out);
        std::fs::create_dir_all(dir.checkpoints().path())
            .with_context(|| format!("run directory {}", dir.path().display()))?;
        let mut started = Instant::now();
        let saved = match resume {
            Resume::Never => None,
            Resume::IfCheckpoint | Resume::Required => {
                dir.checkpoints().read_latest_checkpoint(Weights::Policy)
            }
        };
        let resumed = match saved {
            Some(s) => {
                let wall = learner.resume(&s)?;
                note(format!(
                    "resuming from the policy checkpoint, version {}, training state {} bytes \
                     (crc32 {:08x})",
                    s.version,
                    s.state.len(),
                    s.state_checksum()
                ));
                if let Some(wall) = wall {
                    started = jsae_run_dir::run_started(wall);
                    note(format!(
                        "the run goes on from {} env steps and {wall:.1} s",
                        learner.env_steps()
                    ));
                } else if resume == Resume::Required {
                    let point = ResumePoint::of(&dir)?;
                    learner.count_steps_from(point.env_steps);
                    started = point.started();
                    note(format!(
                        "the run goes on from {} env steps",
                        point.env_steps
                    ));
                }
                true
            }
            None if resume == Resume::Required => anyhow::bail!(
                "--resume: {} holds no policy checkpoint",
                dir.checkpoints().path().display()
            ),
            None => false,
        };
        let mut fresh = !resumed;
        if !resumed && let Some(source) = jsae_run_dir::init_source(config)? {
            learner
                .warm_start(&source.policy)
                .context("--init-from policy")?;
            note(format!("policy warm-started from {}", source.dir.display()));
            fresh = false;
        }
        if !resumed {
            dir.write_config(config)
                .with_context(|| dir.config_toml().display().to_string())?;
        }
        // rows of updates past the checkpoint's (a forged row, or a row of an update whose
        // checkpoint was lost) are cut, so the rows this run writes are not taken for repeats
        let metrics = RunMetrics::open(&dir, &UPDATE_COLUMNS, resumed.then(|| learner.updates()))
            .with_context(|| dir.metrics_csv().display().to_string())?;
        Ok(Self {
            learner,
            dir,
            metrics,
            started,
            fresh,
        })
    }

    /// The learner.
    pub fn learner(&self) -> &Learner {
        &self.learner
    }

    /// The learner, to feed.
    pub fn learner_mut(&mut self) -> &mut Learner {
        &mut self.learner
    }

    /// Seconds since the run started (across resumes).
    pub fn wall_seconds(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    /// The first snapshot, checkpointed: a fresh run's policy first learns from `logged` where
    /// the settings ask (what it did goes to `note`).
    ///
    /// # Errors
    /// Logs the settings ask for and cannot use, or a checkpoint that cannot be written.
    pub fn first_snapshot(
        &mut self,
        logged: Option<&LoggedPurchases>,
        note: &mut dyn FnMut(String),
    ) -> anyhow::Result<PolicySnapshot> {
        if self.fresh {
            for line in self.learner.learn_from_logs(logged)? {
                note(line);
            }
        }
        let first = self.learner.snapshot()?;
        self.checkpoint(&first)?;
        Ok(first)
    }

    /// Writes `snapshot` as the latest policy checkpoint with the training state at this
    /// wall time; before the snapshot goes out, so that a stopped run resumes from it.
    ///
    /// # Errors
    /// When it cannot be written.
    pub fn checkpoint(&self, snapshot: &PolicySnapshot) -> anyhow::Result<()> {
        self.checkpoint_at(snapshot, self.wall_seconds())
    }

    /// [`Self::checkpoint`] with the training state at `wall` seconds.
    fn checkpoint_at(&self, snapshot: &PolicySnapshot, wall: f64) -> anyhow::Result<()> {
        let saved = LatestCheckpoint {
            version: snapshot.version,
            weights: snapshot.bytes.clone(),
            state: self.learner.training_state(wall)?,
        };
        self.dir
            .checkpoints()
            .write_latest_checkpoint(Weights::Policy, &saved)
            .with_context(|| self.dir.checkpoints().path().display().to_string())
    }

    /// Records an update: its checkpoint, then its metrics row (a stop between them leaves a
    /// row missing, never the same update twice), with the embedding it trained on.
    ///
    /// # Errors
    /// When either cannot be written.
    pub fn record_update(
        &mut self,
        report: &UpdateReport,
        embedding: Option<&EmbeddingSnapshot>,
    ) -> anyhow::Result<()> {
        // one wall time for both, so that a resume counts on from the row's
        let wall = self.wall_seconds();
        let row = update_scalars(&report.metrics, wall, embedding);
        self.checkpoint_at(&report.snapshot, wall)?;
        self.metrics
            .record(&row)
            .with_context(|| self.dir.metrics_csv().display().to_string())
    }

    /// Ends the run on the evaluation's report: summary.json, the last policy (and the last
    /// embedding it trained on) as versioned checkpoints, and the evaluation's scalars.
    ///
    /// # Errors
    /// When a file cannot be written.
    pub fn finish(
        &mut self,
        config: &TrainConfig,
        eval: &EvalReport,
        embedding: Option<&EmbeddingSnapshot>,
    ) -> anyhow::Result<Summary> {
        let summary =
            self.learner
                .summary(config, self.learner.env_steps(), self.wall_seconds(), eval);
        let ckpt = self.dir.checkpoints();
        let last = self.learner.snapshot()?;
        ckpt.write_versioned(Weights::Policy, last.version, &last.bytes)?;
        if let Some(e) = embedding {
            ckpt.write_versioned(Weights::Embedding, e.version, &e.bytes)?;
        }
        summary.write(&self.dir)?;
        self.metrics
            .record_eval(summary.env_steps, &summary.eval_scalars())?;
        Ok(summary)
    }
}
