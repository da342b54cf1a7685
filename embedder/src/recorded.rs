//! `--pretrain-from FILE.mcap`: pre-training on a recording's transitions (of random play, or
//! of an earlier run) instead of fresh random play.

use std::path::Path;

use jsae_wire::EmbeddingSnapshot;

use crate::representation::RepresentationModel;
use crate::trainer::EmbedderTrainer;

/// What pre-training from a recording did.
#[derive(Debug, Clone)]
pub struct RecordedPretraining {
    /// The first snapshot (version 1).
    pub snapshot: EmbeddingSnapshot,
    /// Transitions of the recording used: its first `pretrain_budget`, or all it holds.
    pub transitions: usize,
    /// The note to log or print.
    pub note: String,
}

/// Pre-trains `trainer` on the first `pretrain_budget` transitions of the recording at `path`
/// (all of them if it holds fewer), refusing a recording of other state or action spaces.
pub fn pretrain_from_recording<M: RepresentationModel>(
    trainer: &mut EmbedderTrainer<M>,
    path: &Path,
) -> Result<RecordedPretraining, String> {
    let budget = trainer.pretrain_budget();
    let recording = jsae_record::read(path, Some(budget)).map_err(|e| e.to_string())?;
    let (states, actions) = (
        trainer.model().state_space(),
        trainer.model().action_space(),
    );
    if &recording.info.states != states || &recording.info.actions != actions {
        return Err(format!(
            "{}: a recording of {} ({:?}, {:?}), not of this run's spaces ({states:?}, {actions:?})",
            path.display(),
            recording.info.env,
            recording.info.states,
            recording.info.actions
        ));
    }
    let batch = recording
        .transition_batch(path)
        .map_err(|e| e.to_string())?;
    let snapshot = trainer
        .pretrain_on(&batch)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let mut note = format!(
        "embedding pre-trained on {} recorded transitions of {} (of {budget} wanted; model loss {:.4})",
        batch.len(),
        path.display(),
        snapshot.model_loss
    );
    if let Some(why) = &recording.cut_short {
        note.push_str(&format!("; the file ends early: {why}"));
    }
    Ok(RecordedPretraining {
        snapshot,
        transitions: batch.len(),
        note,
    })
}
