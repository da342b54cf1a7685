//! Experiments over many runs: `jsae sweep` runs a grid of envs x algos x seeds x setting
//! overrides, `jsae report` summarises a results folder over seeds; `child` holds the rule
//! for stopping child processes on SIGTERM/SIGINT that `jsae sweep` and `jsae train` share.

pub mod child;
pub mod figures;
pub mod grid;
pub mod report;
pub mod stats;
pub mod sweep;

pub use grid::{Grid, GridError, ReportSpec, RunSpec};
pub use report::{Report, ReportError, report};
pub use sweep::{RunPaths, SweepError, SweepOptions, SweepOutcome, run_sweep};
