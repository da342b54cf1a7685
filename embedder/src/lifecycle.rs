//! The embedder's side of a run directory, in one place for the embedder service and the
//! one-process driver: the trainer opened (resumed from the latest embedding checkpoint, else
//! warm-started from `--init-from`, else pre-trained from a recording where one is given) and
//! each snapshot checkpointed as it is published.

use std::path::{Path, PathBuf};

use jsae_run_dir::{Checkpoints, Resume, Weights};
use jsae_settings::TrainConfig;
use jsae_wire::EmbeddingSnapshot;

use crate::{EmbedderTrainer, pretrain_from_recording};

/// The latest embedding checkpoint in `dir`, if any.
pub fn latest_checkpoint(dir: &Path) -> Option<EmbeddingSnapshot> {
    let (version, bytes) = Checkpoints::new(dir).read_latest(Weights::Embedding)?;
    Some(EmbeddingSnapshot::from_bytes(version, bytes))
}

/// An embedder trainer opened on its checkpoint folder.
#[derive(Debug)]
pub struct EmbedderRun {
    trainer: EmbedderTrainer,
    checkpoints: Option<PathBuf>,
}

impl EmbedderRun {
    /// Opens `trainer` (built for `config`) on `checkpoints` (None: keeps none): resumes from
    /// the latest embedding checkpoint as `resume` says, else warm-starts from
    /// `config.init_from`, and then pre-trains on the recording `pretrain_from` where one is
    /// given (its snapshot checkpointed). Returns the run and the snapshot to act with first
    /// (the resumed or pre-trained one), if any. What it did goes to `note`.
    ///
    /// # Errors
    /// A checkpoint that does not fit where one is required (or none there), a warm start or
    /// a recording that does not fit, or a checkpoint that cannot be written.
    pub fn open(
        config: &TrainConfig,
        mut trainer: EmbedderTrainer,
        checkpoints: Option<&Path>,
        resume: Resume,
        pretrain_from: Option<&Path>,
        note: &mut dyn FnMut(String),
    ) -> Result<(Self, Option<EmbeddingSnapshot>), String> {
        let saved = match (resume, checkpoints) {
            (Resume::Never, _) | (_, None) => None,
            (_, Some(dir)) => latest_checkpoint(dir),
        };
        let mut first = None;
        match (saved, resume) {
            (None, Resume::Required) => {
                return Err(format!(
                    "--resume: no embedding checkpoint in {}",
                    checkpoints.map_or_else(String::new, |d| d.display().to_string())
                ));
            }
            (None, _) => {}
            (Some(saved), _) => match trainer.restore(&saved) {
                Ok(()) => {
                    note(format!(
                        "resuming from the embedding checkpoint, version {}",
                        saved.version
                    ));
                    first = Some(saved);
                }
                Err(e) if resume == Resume::Required => return Err(format!("--resume: {e}")),
                Err(e) => tracing::error!(
                    "the embedding checkpoint in {} does not fit this model ({e}); starting \
                     afresh",
                    checkpoints.map_or_else(String::new, |d| d.display().to_string())
                ),
            },
        }
        let run = Self {
            trainer,
            checkpoints: checkpoints.map(Path::to_path_buf),
        };
        if first.is_some() {
            return Ok((run, first));
        }
        let mut run = run;
        if let Some(source) = jsae_run_dir::init_source(config).map_err(|e| e.to_string())? {
            let parts = run.trainer.warm_start(&source)?;
            note(format!(
                "warm-started from {}: {}",
                source.dir.display(),
                parts.join(", ")
            ));
        }
        if let Some(path) = pretrain_from {
            let done = pretrain_from_recording(&mut run.trainer, path)?;
            note(done.note);
            run.checkpoint(&done.snapshot).map_err(|e| e.to_string())?;
            first = Some(done.snapshot);
        }
        Ok((run, first))
    }

    /// The trainer.
    pub fn trainer(&self) -> &EmbedderTrainer {
        &self.trainer
    }

    /// The trainer, to feed.
    pub fn trainer_mut(&mut self) -> &mut EmbedderTrainer {
        &mut self.trainer
    }

    /// Writes `snap` as `embedding-v{N}.bpk` and as the latest embedding checkpoint (nothing
    /// without a checkpoint folder); before it is handed to anyone.
    ///
    /// # Errors
    /// When a file cannot be written.
    pub fn checkpoint(&self, snap: &EmbeddingSnapshot) -> std::io::Result<()> {
        let Some(dir) = &self.checkpoints else {
            return Ok(());
        };
        // both written whatever the other did (the latest one is what a restart reads)
        let ckpt = Checkpoints::new(dir);
        let versioned = ckpt.write_versioned(Weights::Embedding, snap.version, &snap.bytes);
        let latest = ckpt.write_latest(Weights::Embedding, snap.version, &snap.bytes);
        versioned.and(latest)
    }
}
