//! The run directory and the checkpoint folder: the one place that names their files. Every
//! writer (the learner, the embedder, the one-process driver, the launcher, the plots) and
//! every reader (the Recommender, `jsae plot`, the tests) goes through these paths.
//!
//! ```text
//! DIR/config.toml          every setting of the run
//! DIR/metrics.csv          one row per learner update
//! DIR/summary.json         the result, written last
//! DIR/learning_curve.svg   DIR/action_embeddings.svg, DIR/state_embeddings.svg (gridworld),
//!                          each with its PNG twin (learning_curve.png, ...)
//! DIR/logs/NAME.log        one log per service process (`jsae train` without --one-process)
//! DIR/checkpoints/         policy-vN.bpk, embedding-vN.bpk, and {policy,embedding}-latest.bpk
//!                          with their versions in {policy,embedding}-latest.version
//! ```

use std::io;
use std::path::{Path, PathBuf};

use crate::settings::{Algo, EnvName};

/// A run directory (`--out`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunDir {
    root: PathBuf,
}

impl RunDir {
    /// The run directory at `root`.
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// Where `jsae train` puts a run when `--out` is not given: `runs/ENV-ALGO-seedN`.
    pub fn default_path(env: EnvName, algo: Algo, seed: u64) -> PathBuf {
        PathBuf::from(format!(
            "runs/{}-{}-seed{seed}",
            env.as_str(),
            algo.as_str()
        ))
    }

    /// The directory itself.
    pub fn path(&self) -> &Path {
        &self.root
    }

    /// Every setting of the run (`TrainConfig::to_toml`).
    pub fn config_toml(&self) -> PathBuf {
        self.root.join("config.toml")
    }

    /// One row per learner update.
    pub fn metrics_csv(&self) -> PathBuf {
        self.root.join("metrics.csv")
    }

    /// The run's result, written when the run ends.
    pub fn summary_json(&self) -> PathBuf {
        self.root.join("summary.json")
    }

    /// Training return and success rate against env steps.
    pub fn learning_curve_svg(&self) -> PathBuf {
        self.root.join("learning_curve.svg")
    }

    /// The learned action embeddings (gridworld).
    pub fn action_embeddings_svg(&self) -> PathBuf {
        self.root.join("action_embeddings.svg")
    }

    /// The learned state embeddings (gridworld, representations that embed states).
    pub fn state_embeddings_svg(&self) -> PathBuf {
        self.root.join("state_embeddings.svg")
    }

    /// `DIR/tensorboard/`: TensorBoard event files, the metrics as scalars.
    pub fn tensorboard(&self) -> PathBuf {
        self.root.join("tensorboard")
    }

    /// The service processes' logs.
    pub fn logs(&self) -> PathBuf {
        self.root.join("logs")
    }

    /// The log of one service process (`embedder`, `learner`, `actor-N`).
    pub fn log(&self, process: &str) -> PathBuf {
        self.logs().join(format!("{process}.log"))
    }

    /// The run's checkpoints.
    pub fn checkpoints(&self) -> Checkpoints {
        Checkpoints::new(self.root.join("checkpoints"))
    }

    /// Whether the directory exists and holds anything: a fresh `jsae train` refuses such a
    /// directory unless `--force`, so an older run's checkpoints never mix with a new one's.
    pub fn is_occupied(&self) -> bool {
        std::fs::read_dir(&self.root).is_ok_and(|mut entries| entries.next().is_some())
    }

    /// Removes what a run writes here (the files and folders named above, plots in SVG and
    /// PNG) and nothing else, for `jsae train --force`.
    pub fn clear_run(&self) -> io::Result<()> {
        for dir in [
            self.logs(),
            self.tensorboard(),
            self.root.join("checkpoints"),
        ] {
            match std::fs::remove_dir_all(&dir) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
                _ => {}
            }
        }
        let plots = ["learning_curve", "action_embeddings", "state_embeddings"]
            .into_iter()
            .flat_map(|stem| ["svg", "png"].map(|ext| self.root.join(format!("{stem}.{ext}"))));
        let files = [self.config_toml(), self.metrics_csv(), self.summary_json()];
        for file in files.into_iter().chain(plots) {
            match std::fs::remove_file(&file) {
                Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
                _ => {}
            }
        }
        Ok(())
    }
}

/// What a checkpoint holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weights {
    /// A policy snapshot (the learner's).
    Policy,
    /// An embedding snapshot (the embedder's).
    Embedding,
}

impl Weights {
    fn stem(self) -> &'static str {
        match self {
            Self::Policy => "policy",
            Self::Embedding => "embedding",
        }
    }
}

/// A folder of weight checkpoints: `KIND-vN.bpk` for each kept version, `KIND-latest.bpk` with
/// its version in `KIND-latest.version` for resuming. Writes are atomic (a temporary file,
/// then a rename), so a reader never sees half a file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Checkpoints {
    dir: PathBuf,
}

impl Checkpoints {
    /// The checkpoints in `dir` (the embedder's `--checkpoint-dir`, or a run's).
    pub fn new(dir: impl Into<PathBuf>) -> Self {
        Self { dir: dir.into() }
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// The file of version `version`.
    pub fn versioned(&self, kind: Weights, version: u64) -> PathBuf {
        self.dir.join(format!("{}-v{version}.bpk", kind.stem()))
    }

    /// The file of the latest version.
    pub fn latest(&self, kind: Weights) -> PathBuf {
        self.dir.join(format!("{}-latest.bpk", kind.stem()))
    }

    fn latest_version_file(&self, kind: Weights) -> PathBuf {
        self.dir.join(format!("{}-latest.version", kind.stem()))
    }

    /// Writes version `version` as `KIND-vN.bpk`.
    pub fn write_versioned(&self, kind: Weights, version: u64, bytes: &[u8]) -> io::Result<()> {
        write_atomic(&self.versioned(kind, version), bytes)
    }

    /// Writes the latest version (the bytes first, then the version that names them).
    pub fn write_latest(&self, kind: Weights, version: u64, bytes: &[u8]) -> io::Result<()> {
        write_atomic(&self.latest(kind), bytes)?;
        write_atomic(
            &self.latest_version_file(kind),
            format!("{version}\n").as_bytes(),
        )
    }

    /// The latest version and its bytes, if both are there.
    pub fn read_latest(&self, kind: Weights) -> Option<(u64, Vec<u8>)> {
        let version = std::fs::read_to_string(self.latest_version_file(kind))
            .ok()?
            .trim()
            .parse()
            .ok()?;
        let bytes = std::fs::read(self.latest(kind)).ok()?;
        Some((version, bytes))
    }

    /// Removes the latest files (a fresh run in a directory that held an older one).
    pub fn clear_latest(&self) {
        for kind in [Weights::Policy, Weights::Embedding] {
            let _ = std::fs::remove_file(self.latest(kind));
            let _ = std::fs::remove_file(self.latest_version_file(kind));
        }
    }

    /// The newest version in the folder and its file: the highest of `KIND-vN.bpk` and the
    /// latest file's version.
    pub fn newest(&self, kind: Weights) -> Option<(u64, PathBuf)> {
        let mut best: Option<(u64, PathBuf)> =
            std::fs::read_to_string(self.latest_version_file(kind))
                .ok()
                .and_then(|v| v.trim().parse().ok())
                .map(|v| (v, self.latest(kind)));
        let prefix = format!("{}-v", kind.stem());
        for entry in std::fs::read_dir(&self.dir).ok()?.flatten() {
            let file = entry.file_name();
            let version = file
                .to_str()
                .and_then(|f| f.strip_prefix(&prefix))
                .and_then(|f| f.strip_suffix(".bpk"))
                .and_then(|v| v.parse::<u64>().ok());
            if let Some(v) = version
                && best.as_ref().is_none_or(|b| v > b.0)
            {
                best = Some((v, entry.path()));
            }
        }
        best
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename
/// (creating the folder if needed).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .map_or_else(|| "checkpoint".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(".{name}.tmp"));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newest_is_the_highest_version_and_latest_round_trips() {
        let dir = std::env::temp_dir().join(format!("jsae-run-dir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = RunDir::new(&dir).checkpoints();
        assert_eq!(c.newest(Weights::Policy), None);
        c.write_versioned(Weights::Policy, 3, b"three")
            .expect("write");
        c.write_versioned(Weights::Policy, 12, b"twelve")
            .expect("write");
        c.write_latest(Weights::Policy, 7, b"seven").expect("write");
        let (v, path) = c.newest(Weights::Policy).expect("newest");
        assert_eq!(
            (v, std::fs::read(path).expect("read")),
            (12, b"twelve".to_vec())
        );
        assert_eq!(c.read_latest(Weights::Policy), Some((7, b"seven".to_vec())));
        assert_eq!(c.read_latest(Weights::Embedding), None);
        c.clear_latest();
        assert_eq!(c.read_latest(Weights::Policy), None);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn clearing_a_run_removes_its_files_and_keeps_others() {
        let dir = std::env::temp_dir().join(format!("jsae-run-clear-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let run = RunDir::new(&dir);
        assert!(!run.is_occupied());
        run.checkpoints()
            .write_latest(Weights::Policy, 2, b"two")
            .expect("write");
        for f in [run.metrics_csv(), run.summary_json(), dir.join("notes.txt")] {
            std::fs::write(f, "x").expect("write");
        }
        assert!(run.is_occupied());
        run.clear_run().expect("clear");
        assert!(!run.checkpoints().path().exists() && !run.metrics_csv().exists());
        assert!(!run.summary_json().exists() && dir.join("notes.txt").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
