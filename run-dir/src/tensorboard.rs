//! The run's metrics for TensorBoard: every scalar of a metrics row into event files under
//! `DIR/tensorboard/`, tagged with its metrics.csv column name and stepped by env steps, and
//! the final evaluation under `eval/` (the files: `event_file`).

use std::io;
use std::path::Path;

use crate::event_file::EventFile;
use crate::metrics::{CsvMetrics, MetricsSink, Scalar};

/// The column a row's step is read from.
const STEP: &str = "env_steps";

/// Rows of scalars as TensorBoard scalars.
#[derive(Debug)]
pub struct TensorBoardMetrics {
    file: EventFile,
    last_step: u64,
}

impl TensorBoardMetrics {
    /// A new event file in `dir` (created if missing; the files of an earlier process stay,
    /// and TensorBoard reads them all).
    pub fn create(dir: &Path) -> io::Result<Self> {
        Ok(Self {
            file: EventFile::create(dir)?,
            last_step: 0,
        })
    }

    /// The row's finite values, tagged `PREFIX+column`, as one event at `step`.
    fn write(&mut self, prefix: &str, step: u64, row: &[Scalar]) -> io::Result<()> {
        let scalars = row.iter().filter_map(|(name, value)| {
            let v = value.filter(|v| v.is_finite())?;
            Some((format!("{prefix}{name}"), v as f32))
        });
        self.file.write_scalars(step, scalars)
    }
}

impl MetricsSink for TensorBoardMetrics {
    fn record(&mut self, row: &[Scalar]) -> io::Result<()> {
        let step = row
            .iter()
            .find(|(name, _)| *name == STEP)
            .and_then(|(_, v)| *v)
            .map_or(self.last_step, |v| v as u64);
        self.last_step = step;
        self.write("", step, row)
    }

    fn record_eval(&mut self, env_steps: u64, row: &[Scalar]) -> io::Result<()> {
        self.write("eval/", env_steps, row)
    }
}

/// A run's metrics: `metrics.csv` and the TensorBoard event files, row for row.
#[derive(Debug)]
pub struct RunMetrics {
    csv: CsvMetrics,
    tensorboard: TensorBoardMetrics,
}

impl RunMetrics {
    /// Both sinks of the run directory `run`: metrics.csv created (`append`: opened to add
    /// rows, a resumed learner) with `columns`, and a new event file.
    pub fn open(
        run: &crate::RunDir,
        columns: &[&'static str],
        resumed_at: Option<u64>,
    ) -> io::Result<Self> {
        let csv = match resumed_at {
            Some(updates) => CsvMetrics::append(&run.metrics_csv(), columns, updates)?,
            None => CsvMetrics::create(&run.metrics_csv(), columns)?,
        };
        Ok(Self {
            csv,
            tensorboard: TensorBoardMetrics::create(&run.tensorboard())?,
        })
    }

    /// metrics.csv's path.
    pub fn csv_path(&self) -> &Path {
        self.csv.path()
    }
}

impl MetricsSink for RunMetrics {
    fn record(&mut self, row: &[Scalar]) -> io::Result<()> {
        // an update already recorded (a restarted learner): in neither sink again
        if self.csv.is_repeat(row) {
            return Ok(());
        }
        self.csv.record(row)?;
        self.tensorboard.record(row)
    }

    fn record_eval(&mut self, env_steps: u64, row: &[Scalar]) -> io::Result<()> {
        self.tensorboard.record_eval(env_steps, row)
    }
}
