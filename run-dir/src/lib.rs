//! The run directory: the one place that names its files and reads and writes them.
//!
//! Layout: `dir` (the directory and the checkpoint folder: file names, atomic writes, the
//! newest checkpoint of each kind; re-exported at the root), `checkpoint_file` (the latest
//! checkpoint's layout and checksum), `resume` (whether a component goes on from its
//! checkpoint), `init` (`--init-from RUN`: the finished run a new
//! run warm-starts from), `metrics` (named scalars into a sink: metrics.csv, read back as a
//! table; where a resumed run goes on from), `tensorboard` (the same scalars as TensorBoard
//! event files, written by `event_file`; `RunMetrics` writes both; feature `tensorboard`, which the trainers turn on)
//! and `summary` (summary.json).

#![forbid(unsafe_code)]

mod checkpoint_file;
mod dir;
#[cfg(feature = "tensorboard")]
mod event_file;
mod init;
mod metrics;
mod resume;
mod summary;
#[cfg(feature = "tensorboard")]
mod tensorboard;

pub use dir::*;
pub use init::{InitSource, init_source};
pub use metrics::{
    CsvMetrics, MetricsReadError, MetricsSink, MetricsTable, ResumePoint, Scalar, run_started,
};
pub use resume::Resume;
pub use summary::{COMMAND_LINE_ENV, EvalStats, RunMeta, Summary};
#[cfg(feature = "tensorboard")]
pub use tensorboard::{RunMetrics, TensorBoardMetrics};
