//! Training the JSAE embedding model (and the AE and RA baselines that share its inference
//! side): the losses, the trainer and the embedder service. The model's structure and the
//! inference side actors use (phi, f, the nearest action, a snapshot loaded for acting) are
//! `jsae_agent`'s.
//!
//! phi maps states to `X = R^m`, g maps actions to `E = R^d`, T predicts the next state from
//! `concat(phi(s), g(a))`, and f maps `E` back to actions (exact nearest neighbour over the
//! g-table for discrete actions, an MLP for continuous ones). phi, g and T minimise
//! `-log P(s'|s,a)`; f is trained on detached `g(a)`. RL losses never touch this model.
//!
//! Layout: `lifecycle` (the trainer on its checkpoints: resume, warm start, pre-training
//! from a recording, a checkpoint per snapshot, for the service and the one-process driver
//! alike), `model` (the losses: [`EmbeddingTraining`]), `recorded` (pre-training from a recording), `replay` (the bounded transition buffer), `representation` (the seam: the
//! trait every trained representation implements), `structure` (how much of the action
//! geometry g holds), `trainer` (pre-training, continuous
//! updates, versioned snapshots), `service` (the gRPC embedder service). The settings
//! are `jsae_settings::EmbeddingConfig`.

#![forbid(unsafe_code)]

mod catalogue;
pub mod lifecycle;
mod model;
mod pretrain_progress;
mod recorded;
pub mod replay;
mod representation;
pub mod service;
mod structure;
mod trainer;

pub use jsae_settings::EmbeddingConfig;
pub use model::{EmbeddingTraining, cross_entropy};
pub use pretrain_progress::{PRETRAIN_PHASE, PretrainProgress};
pub use recorded::{RecordedPretraining, pretrain_from_recording};
pub use representation::{RepresentationModel, TrainingModel};
pub use structure::ActionStructure;
pub use trainer::{
    CountedEstimate, EmbedderStats, EmbedderTrainer, LoggedItems, LoggedReport, LookaheadEstimate,
};
