//! Experiments over many runs: `jsae sweep` runs a grid of envs x algos x seeds x setting
//! overrides (`grid`: the sweep file; `sweep`: running it N at a time, resumable); `child`
//! holds the rule for stopping child processes on SIGTERM/SIGINT that `jsae sweep` and
//! `jsae train` share. The sweep's report (`jsae report`) is jsae-report's.

pub mod child;
pub mod grid;
pub mod sweep;

pub use grid::{Grid, GridError, ReportSpec, RunSpec};
pub use sweep::{RunPaths, SweepError, SweepOptions, SweepOutcome, run_sweep};
