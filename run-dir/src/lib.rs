//! The run directory: the one place that names its files and reads and writes them.
//!
//! Layout: `dir` (the directory and the checkpoint folder: file names, atomic writes, the
//! newest checkpoint of each kind; re-exported at the root), `checkpoint_file` (the latest
//! checkpoint's layout and checksum), `init` (`--init-from RUN`: the finished run a new
//! run warm-starts from), `metrics` (named scalars into a sink: metrics.csv, read back as a
//! table; where a resumed run goes on from), `tensorboard` (the same scalars as TensorBoard
//! event files; `RunMetrics` writes both) and `summary` (summary.json).

#![forbid(unsafe_code)]

mod checkpoint_file;
mod dir;
mod init;
mod metrics;
mod summary;
mod tensorboard;

pub use dir::*;
pub use init::{InitSource, init_source};
pub use metrics::{
    CsvMetrics, MetricsReadError, MetricsSink, MetricsTable, ResumePoint, Scalar, run_started,
};
pub use summary::{COMMAND_LINE_ENV, EvalStats, RunMeta, Summary};
pub use tensorboard::{RunMetrics, TensorBoardMetrics};
