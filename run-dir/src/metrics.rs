//! Run metrics as named scalars: whoever measures something hands a row of `(name, value)`
//! pairs to a [`MetricsSink`], which decides how to keep them. [`CsvMetrics`] writes
//! `metrics.csv` (one row per update, flushed as it is written so a crash loses nothing
//! already reported); [`MetricsTable`] reads it back by column name.

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

/// One named value; `None` is an empty cell (no episode ended, no embedding yet).
pub type Scalar = (&'static str, Option<f64>);

/// Where rows of named scalars go.
pub trait MetricsSink: Send {
    /// Keeps one row. Every row of a sink names the same scalars in the same order.
    fn record(&mut self, row: &[Scalar]) -> io::Result<()>;

    /// Keeps the final evaluation's scalars ([`crate::Summary::eval_scalars`]), taken at
    /// `env_steps`; sinks without a place for them ignore them.
    fn record_eval(&mut self, env_steps: u64, row: &[Scalar]) -> io::Result<()> {
        let _ = (env_steps, row);
        Ok(())
    }
}

/// `metrics.csv`: a header of the columns' names, then one row per record.
#[derive(Debug)]
pub struct CsvMetrics {
    writer: csv::Writer<File>,
    path: PathBuf,
    columns: Vec<&'static str>,
    /// The highest `update` written: a row of an update already there (a learner restarted
    /// from a checkpoint older than its last row) is not written again.
    last_update: Option<f64>,
}

impl CsvMetrics {
    /// Creates (or empties) the file and writes its header.
    pub fn create(path: &Path, columns: &[&'static str]) -> io::Result<Self> {
        let mut writer = csv::Writer::from_writer(File::create(path)?);
        writer.write_record(columns)?;
        writer.flush()?;
        Ok(Self {
            writer,
            path: path.to_path_buf(),
            columns: columns.to_vec(),
            last_update: None,
        })
    }

    /// Opens the file to add rows (a learner resumed from a checkpoint after `updates`
    /// updates), or creates it. Rows of a later update (a forged row, or a row of an update
    /// whose checkpoint was lost) are cut first, with a warning naming the file: rows are
    /// idempotent by `update`, so they would silence every row to come.
    pub fn append(path: &Path, columns: &[&'static str], updates: u64) -> io::Result<Self> {
        let has_header = std::fs::metadata(path).is_ok_and(|m| m.len() > 0);
        if !has_header {
            return Self::create(path, columns);
        }
        // A run started by another version may have other columns: refuse, not mix them.
        let text = std::fs::read_to_string(path)
            .map_err(|e| io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
        let header = text.lines().next().unwrap_or("");
        if !header.split(',').eq(columns.iter().copied()) {
            return Err(io::Error::other(format!(
                "{}: its columns ({header}) are not this version's; resume the run with the \
                 version that started it",
                path.display()
            )));
        }
        let text = cut_rows_past(path, &text, updates)?;
        let file = std::fs::OpenOptions::new().append(true).open(path)?;
        if !text.ends_with('\n') {
            // a row torn by a crash mid-write: dropped, so the next one starts on its own line
            file.set_len(complete_rows(&text).len() as u64)?;
        }
        let last_update = MetricsTable::parse(complete_rows(&text))
            .ok()
            .and_then(|t| t.column("update").into_iter().flatten().reduce(f64::max));
        Ok(Self {
            writer: csv::Writer::from_writer(file),
            path: path.to_path_buf(),
            columns: columns.to_vec(),
            last_update,
        })
    }

    /// Whether `row` is of an update the file holds already (rows are idempotent by
    /// `update`: such a row is not written again).
    pub fn is_repeat(&self, row: &[Scalar]) -> bool {
        let update = row
            .iter()
            .find(|(name, _)| *name == "update")
            .and_then(|s| s.1);
        matches!((update, self.last_update), (Some(u), Some(last)) if u <= last)
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl MetricsSink for CsvMetrics {
    fn record(&mut self, row: &[Scalar]) -> io::Result<()> {
        if !row
            .iter()
            .map(|(name, _)| *name)
            .eq(self.columns.iter().copied())
        {
            return Err(io::Error::other(format!(
                "{}: a row whose names are not the columns {:?}",
                self.path.display(),
                self.columns
            )));
        }
        if self.is_repeat(row) {
            return Ok(());
        }
        self.writer.write_record(
            row.iter()
                .map(|(_, v)| v.map(|x| x.to_string()).unwrap_or_default()),
        )?;
        if let Some(u) = row
            .iter()
            .find(|(name, _)| *name == "update")
            .and_then(|s| s.1)
        {
            self.last_update = Some(self.last_update.map_or(u, |last| last.max(u)));
        }
        self.writer.flush()
    }
}

/// Why a metrics file could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {source}")]
pub struct MetricsReadError {
    path: PathBuf,
    source: csv::Error,
}

/// `text` (the file at `path`) without its complete rows whose `update` is not a number up
/// to `updates`; the file is rewritten (beside, then renamed) when any is cut. A file
/// without an `update` column is left as it is.
fn cut_rows_past(path: &Path, text: &str, updates: u64) -> io::Result<String> {
    let mut lines = complete_rows(text).lines();
    let header = lines.next().unwrap_or("");
    let Some(at) = header.split(',').position(|c| c == "update") else {
        return Ok(text.to_owned());
    };
    let kept = |row: &str| {
        let update = row.split(',').nth(at).and_then(|v| v.parse::<f64>().ok());
        update.is_some_and(|u| u <= updates as f64)
    };
    let rows: Vec<&str> = lines.collect();
    let cut = rows.iter().filter(|r| !kept(r)).count();
    if cut == 0 {
        return Ok(text.to_owned());
    }
    tracing::warn!(
        "{}: {cut} rows of updates past the checkpoint's {updates} (or without an update \
         number) cut",
        path.display()
    );
    let mut kept_text = format!("{header}\n");
    for row in rows.iter().filter(|r| kept(r)) {
        kept_text.push_str(row);
        kept_text.push('\n');
    }
    let tmp = path.with_extension("csv.cut");
    std::fs::write(&tmp, &kept_text)?;
    std::fs::rename(&tmp, path)?;
    Ok(kept_text)
}

/// The text up to its last line end: the complete rows of a file a crash may have cut.
fn complete_rows(text: &str) -> &str {
    &text[..text.rfind('\n').map_or(0, |i| i + 1)]
}

/// Where a stopped run goes on from (`jsae train --resume`): the env steps and wall seconds
/// of its last metrics.csv row; zero for a run without rows.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ResumePoint {
    /// Env steps of all actors at the last update.
    pub env_steps: u64,
    /// Wall seconds of the run at the last update.
    pub wall_seconds: f64,
}

impl ResumePoint {
    /// The last complete row of `run`'s metrics.csv (a row torn by a crash is left out; zero
    /// where the file has no row or is missing); an error where the file does not read.
    pub fn of(run: &crate::RunDir) -> io::Result<Self> {
        let path = run.metrics_csv();
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(Self::default()),
            Err(e) => return Err(io::Error::new(e.kind(), format!("{}: {e}", path.display()))),
        };
        let table = MetricsTable::parse(complete_rows(&text))
            .map_err(|e| io::Error::other(format!("{}: {e}", path.display())))?;
        let last = |name: &str| table.column(name).last().copied().flatten();
        Ok(Self {
            env_steps: last("env_steps").map_or(0, |s| s as u64),
            wall_seconds: last("wall_seconds").unwrap_or(0.0),
        })
    }

    /// The start instant a resumed process measures wall time from, so that it counts on
    /// from this point's wall seconds.
    pub fn started(&self) -> std::time::Instant {
        run_started(self.wall_seconds)
    }
}

/// The instant a run that had run `wall_seconds` before this process started (a restarted
/// or resumed learner) measures its wall time from, so that its wall time counts on.
pub fn run_started(wall_seconds: f64) -> std::time::Instant {
    let now = std::time::Instant::now();
    let before = std::time::Duration::try_from_secs_f64(wall_seconds.max(0.0)).unwrap_or_default();
    now.checked_sub(before).unwrap_or(now)
}

/// A metrics file read back: its column names and its rows (empty cells are `None`; a cell
/// that is no number too).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MetricsTable {
    columns: Vec<String>,
    rows: Vec<Vec<Option<f64>>>,
}

impl MetricsTable {
    /// Reads a `metrics.csv`.
    pub fn read(path: &Path) -> Result<Self, MetricsReadError> {
        let error = |source| MetricsReadError {
            path: path.to_path_buf(),
            source,
        };
        let mut reader = csv::Reader::from_path(path).map_err(error)?;
        Self::from_reader(&mut reader).map_err(error)
    }

    /// Parses the text of a `metrics.csv`.
    pub fn parse(text: &str) -> Result<Self, csv::Error> {
        Self::from_reader(&mut csv::Reader::from_reader(text.as_bytes()))
    }

    fn from_reader<R: io::Read>(reader: &mut csv::Reader<R>) -> Result<Self, csv::Error> {
        let columns = reader.headers()?.iter().map(str::to_owned).collect();
        let rows = reader
            .records()
            .map(|r| Ok(r?.iter().map(|c| c.parse().ok()).collect()))
            .collect::<Result<_, csv::Error>>()?;
        Ok(Self { columns, rows })
    }

    /// The column names.
    pub fn columns(&self) -> &[String] {
        &self.columns
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether there is no row.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The values of column `name`, one per row (`None` for an empty cell; all `None` for a
    /// column the file does not have).
    pub fn column(&self, name: &str) -> Vec<Option<f64>> {
        let index = self.columns.iter().position(|c| c == name);
        self.rows
            .iter()
            .map(|row| index.and_then(|i| row.get(i).copied().flatten()))
            .collect()
    }

    /// `(x, y)` pairs of two columns, for the rows where both are set.
    pub fn series(&self, x: &str, y: &str) -> Vec<(f64, f64)> {
        self.column(x)
            .into_iter()
            .zip(self.column(y))
            .filter_map(|(a, b)| Some((a?, b?)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_written_by_name_read_back_by_name() {
        let path = std::env::temp_dir().join(format!("jsae-metrics-{}.csv", std::process::id()));
        let columns = ["env_steps", "return_mean"];
        let mut sink = CsvMetrics::create(&path, &columns).expect("create");
        assert_eq!(
            MetricsTable::read(&path).expect("header").columns(),
            columns
        );
        sink.record(&[("env_steps", Some(2048.0)), ("return_mean", None)])
            .expect("row");
        assert!(sink.record(&[("return_mean", None)]).is_err());
        drop(sink);
        let mut sink = CsvMetrics::append(&path, &columns, 1).expect("append");
        sink.record(&[("env_steps", Some(4096.0)), ("return_mean", Some(-0.25))])
            .expect("row");
        let table = MetricsTable::read(&path).expect("read");
        assert_eq!(table.columns(), ["env_steps", "return_mean"]);
        assert_eq!(table.column("return_mean"), [None, Some(-0.25)]);
        assert_eq!(table.series("env_steps", "return_mean"), [(4096.0, -0.25)]);
        assert_eq!(table.column("missing"), [None, None]);
        let _ = std::fs::remove_file(path);
    }

    #[test]
    fn a_row_torn_by_a_crash_is_dropped_on_resume() {
        let dir = std::env::temp_dir().join(format!("jsae-torn-{}", std::process::id()));
        let run = crate::RunDir::new(&dir);
        std::fs::create_dir_all(&dir).expect("dir");
        std::fs::write(
            run.metrics_csv(),
            "env_steps,wall_seconds\n2048,1.5\n4096,3.0\n61",
        )
        .expect("write");
        let point = ResumePoint::of(&run).expect("reads");
        assert_eq!((point.env_steps, point.wall_seconds), (4096, 3.0));
        let columns = ["env_steps", "wall_seconds"];
        let mut sink = CsvMetrics::append(&run.metrics_csv(), &columns, 2).expect("append");
        sink.record(&[("env_steps", Some(6144.0)), ("wall_seconds", Some(4.5))])
            .expect("row");
        let table = MetricsTable::read(&run.metrics_csv()).expect("read");
        assert_eq!(
            table.column("env_steps"),
            [Some(2048.0), Some(4096.0), Some(6144.0)]
        );
        // rows are idempotent by update (F5: a learner restarted from a checkpoint older
        // than its last row does not write that update twice)
        let columns = ["update", "env_steps"];
        let path = dir.join("updates.csv");
        std::fs::write(&path, "update,env_steps\n1,2048\n2,4096\n").expect("write");
        let mut sink = CsvMetrics::append(&path, &columns, 2).expect("append");
        for (u, steps) in [(2.0, 4100.0), (3.0, 6144.0), (3.0, 6150.0)] {
            sink.record(&[("update", Some(u)), ("env_steps", Some(steps))])
                .expect("row");
        }
        let table = MetricsTable::read(&path).expect("read");
        assert_eq!(table.column("update"), [Some(1.0), Some(2.0), Some(3.0)]);
        assert_eq!(table.column("env_steps")[2], Some(6144.0));
        assert_eq!(
            ResumePoint::of(&crate::RunDir::new(dir.join("none"))).expect("none"),
            ResumePoint::default()
        );
        // a forged row far past the checkpoint's update is cut, so later rows are written
        std::fs::write(&path, "update,env_steps\n1,2048\n999999,1\n2,4096\nx,5\n").expect("write");
        let mut sink = CsvMetrics::append(&path, &columns, 2).expect("append");
        sink.record(&[("update", Some(3.0)), ("env_steps", Some(6144.0))])
            .expect("row");
        let table = MetricsTable::read(&path).expect("read");
        assert_eq!(table.column("update"), [Some(1.0), Some(2.0), Some(3.0)]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
