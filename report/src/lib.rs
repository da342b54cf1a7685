//! Every figure and report, with one plotting home (`figures`: the font, the colours, the
//! SVG and PNG twins): a run's plots (`plot`: the learning curve, the gridworld's learned
//! embeddings; `jsae plot`) and a results folder summarised over seeds (`report`, with the
//! statistics in `stats`; `jsae report`).

#![forbid(unsafe_code)]

mod error;
pub mod figures;
pub mod plot;
pub mod report;
pub mod stats;

pub use report::{Report, ReportError, report};
