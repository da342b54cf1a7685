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
//! DIR/checkpoints/         policy-vN.bpk, embedding-vN.bpk (the weights), and
//!                          {policy,embedding}-latest.ckpt (version, weights, training state,
//!                          checksum) with the one each replaced, {policy,embedding}-previous.ckpt
//! ```

use std::io::{self, Write};
use std::path::{Path, PathBuf};

use crate::checkpoint_file::peek_version;
pub use crate::checkpoint_file::{LatestCheckpoint, read_weights};
use jsae_settings::{Algo, EnvName};

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

    /// Writes `config` as the run's config.toml, atomically (a service reading it meanwhile
    /// sees the old file or the new one, never half of one).
    pub fn write_config(&self, config: &jsae_settings::TrainConfig) -> io::Result<()> {
        write_atomic(&self.config_toml(), config.to_toml().as_bytes())
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

/// A folder of weight checkpoints: `KIND-vN.bpk` for each kept version (the weights as
/// written), and `KIND-latest.ckpt` for resuming: one file with its version, the weights, the
/// training state and a checksum ([`LatestCheckpoint`]); the one it replaced stays as
/// `KIND-previous.ckpt`. Every write goes to a temporary file that is flushed to disk before
/// it is renamed into place, and the folder is flushed after the rename, so that a crash or a
/// power cut leaves the old file or the new one, never half of one. A latest file whose
/// checksum fails is refused (logged) and the previous one read instead.
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

    /// The latest checkpoint's file (read it with [`read_weights`] or
    /// [`Self::read_latest_checkpoint`]).
    pub fn latest(&self, kind: Weights) -> PathBuf {
        self.dir.join(format!("{}-latest.ckpt", kind.stem()))
    }

    /// The latest checkpoint before the current one.
    fn previous(&self, kind: Weights) -> PathBuf {
        self.dir.join(format!("{}-previous.ckpt", kind.stem()))
    }

    /// Writes version `version` as `KIND-vN.bpk`.
    pub fn write_versioned(&self, kind: Weights, version: u64, bytes: &[u8]) -> io::Result<()> {
        write_atomic(&self.versioned(kind, version), bytes)
    }

    /// Writes the latest version's weights (no training state).
    pub fn write_latest(&self, kind: Weights, version: u64, bytes: &[u8]) -> io::Result<()> {
        self.write_latest_checkpoint(
            kind,
            &LatestCheckpoint {
                version,
                weights: bytes.to_vec(),
                state: Vec::new(),
            },
        )
    }

    /// Writes the latest checkpoint; the one it replaces becomes the previous one.
    pub fn write_latest_checkpoint(
        &self,
        kind: Weights,
        checkpoint: &LatestCheckpoint,
    ) -> io::Result<()> {
        let latest = self.latest(kind);
        let tmp = write_synced_temp(&latest, &checkpoint.encode())?;
        match std::fs::rename(&latest, self.previous(kind)) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
            _ => {}
        }
        std::fs::rename(&tmp, &latest)?;
        sync_dir(&self.dir)
    }

    /// The latest version and its weights, if a good latest (or previous) checkpoint is
    /// there.
    pub fn read_latest(&self, kind: Weights) -> Option<(u64, Vec<u8>)> {
        self.read_latest_checkpoint(kind)
            .map(|c| (c.version, c.weights))
    }

    /// The latest checkpoint; where the latest file is damaged (its checksum fails, it is
    /// torn) or missing, the previous one, with the reason logged; `None` where neither is
    /// good.
    pub fn read_latest_checkpoint(&self, kind: Weights) -> Option<LatestCheckpoint> {
        for path in [self.latest(kind), self.previous(kind)] {
            let bytes = match std::fs::read(&path) {
                Ok(bytes) => bytes,
                Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                Err(e) => {
                    tracing::warn!("checkpoint {}: {e}; not used", path.display());
                    continue;
                }
            };
            match LatestCheckpoint::decode(&bytes) {
                Ok(c) => return Some(c),
                Err(e) => tracing::warn!(
                    "checkpoint {} refused: {e}; falling back to the previous one, if any",
                    path.display()
                ),
            }
        }
        None
    }

    /// An error naming the latest checkpoint files of `kind` when some are there and none can
    /// be read (each refusal is logged by [`Self::read_latest_checkpoint`]): a service that
    /// started afresh would overwrite them (and a learner its run's metrics), so it refuses
    /// to start instead.
    pub fn refuse_unreadable(&self, kind: Weights) -> Result<(), String> {
        let present: Vec<String> = [self.latest(kind), self.previous(kind)]
            .into_iter()
            .filter(|p| p.exists())
            .map(|p| p.display().to_string())
            .collect();
        if present.is_empty() || self.read_latest_checkpoint(kind).is_some() {
            return Ok(());
        }
        Err(format!(
            "{} cannot be read (damaged or torn): starting afresh \
             would overwrite them. Restore them from a backup, or move them away to start \
             again from version 0",
            present.join(" and ")
        ))
    }

    /// Removes the latest files (a fresh run in a directory that held an older one), and the
    /// `KIND-latest.bpk`/`.version` pairs older builds wrote.
    pub fn clear_latest(&self) {
        for kind in [Weights::Policy, Weights::Embedding] {
            let stem = kind.stem();
            let legacy = [
                self.dir.join(format!("{stem}-latest.bpk")),
                self.dir.join(format!("{stem}-latest.version")),
            ];
            for file in [self.latest(kind), self.previous(kind)]
                .into_iter()
                .chain(legacy)
            {
                let _ = std::fs::remove_file(file);
            }
        }
    }

    /// The newest version in the folder and its file: the highest of `KIND-vN.bpk` and the
    /// latest checkpoint's version (its header; the previous file's where the latest is
    /// unreadable). Read the file with [`read_weights`].
    pub fn newest(&self, kind: Weights) -> Option<(u64, PathBuf)> {
        let mut best: Option<(u64, PathBuf)> = [self.latest(kind), self.previous(kind)]
            .into_iter()
            .find_map(|path| peek_version(&path).ok().map(|v| (v, path)));
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

/// Writes `bytes` next to `path` in a temporary file, flushed to disk; returns its path.
fn write_synced_temp(path: &Path, bytes: &[u8]) -> io::Result<PathBuf> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .map_or_else(|| "checkpoint".into(), |n| n.to_string_lossy().into_owned());
    let tmp = dir.join(format!(".{name}.tmp"));
    let mut file = std::fs::File::create(&tmp)?;
    file.write_all(bytes)?;
    file.sync_all()?;
    Ok(tmp)
}

/// Flushes a folder's entries (a rename into it) to disk; a no-op where the platform cannot
/// open a folder as a file.
fn sync_dir(dir: &Path) -> io::Result<()> {
    match std::fs::File::open(dir) {
        Ok(d) => d.sync_all(),
        Err(_) => Ok(()),
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder, flushed to disk
/// before the rename, and flushes the folder after it (creating the folder if needed).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let tmp = write_synced_temp(path, bytes)?;
    std::fs::rename(&tmp, path)?;
    sync_dir(path.parent().unwrap_or(Path::new(".")))
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
            (v, read_weights(&path).expect("read")),
            (12, b"twelve".to_vec())
        );
        c.write_latest(Weights::Policy, 13, b"thirteen")
            .expect("write");
        let (v, path) = c.newest(Weights::Policy).expect("newest");
        assert_eq!(
            (v, read_weights(&path).expect("read")),
            (13, b"thirteen".to_vec())
        );
        c.write_latest(Weights::Policy, 7, b"seven").expect("write");
        assert_eq!(c.read_latest(Weights::Policy), Some((7, b"seven".to_vec())));
        assert_eq!(c.read_latest(Weights::Embedding), None);
        c.clear_latest();
        assert_eq!(c.read_latest(Weights::Policy), None);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_damaged_latest_checkpoint_is_refused_and_the_previous_one_read() {
        let dir = std::env::temp_dir().join(format!("jsae-run-damaged-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let c = RunDir::new(&dir).checkpoints();
        c.write_latest(Weights::Policy, 1, b"one").expect("write");
        c.write_latest(Weights::Policy, 2, b"two").expect("write");
        assert_eq!(c.read_latest(Weights::Policy), Some((2, b"two".to_vec())));
        // a bit flipped on disk in the newest weights
        let mut bytes = std::fs::read(c.latest(Weights::Policy)).expect("read");
        let at = bytes.len() - 6;
        bytes[at] ^= 0x01;
        std::fs::write(c.latest(Weights::Policy), bytes).expect("write");
        assert_eq!(c.read_latest(Weights::Policy), Some((1, b"one".to_vec())));
        assert!(read_weights(&c.latest(Weights::Policy)).is_err());
        // torn: cut short (the damaged file went on to be the previous one, then out)
        c.write_latest(Weights::Policy, 3, b"three").expect("write");
        c.write_latest(Weights::Policy, 4, b"four").expect("write");
        let bytes = std::fs::read(c.latest(Weights::Policy)).expect("read");
        std::fs::write(c.latest(Weights::Policy), &bytes[..bytes.len() - 3]).expect("write");
        assert_eq!(c.read_latest(Weights::Policy), Some((3, b"three".to_vec())));
        // both damaged: none to read, and a fresh start refused, naming both files
        assert_eq!(c.refuse_unreadable(Weights::Policy), Ok(()));
        std::fs::write(c.previous(Weights::Policy), b"garbage").expect("write");
        assert_eq!(c.read_latest(Weights::Policy), None);
        let refused = c
            .refuse_unreadable(Weights::Policy)
            .expect_err("both damaged");
        assert!(
            refused.contains("policy-latest.ckpt") && refused.contains("policy-previous.ckpt"),
            "{refused}"
        );
        assert_eq!(
            c.refuse_unreadable(Weights::Embedding),
            Ok(()),
            "none there"
        );
        // both gone: none
        std::fs::remove_file(c.latest(Weights::Policy)).expect("rm");
        std::fs::remove_file(c.previous(Weights::Policy)).expect("rm");
        assert_eq!(c.read_latest(Weights::Policy), None);
        assert_eq!(c.refuse_unreadable(Weights::Policy), Ok(()));
        // the state travels with the weights, in the same file
        let saved = LatestCheckpoint {
            version: 5,
            weights: b"five".to_vec(),
            state: b"adam".to_vec(),
        };
        c.write_latest_checkpoint(Weights::Policy, &saved)
            .expect("write");
        assert_eq!(c.read_latest_checkpoint(Weights::Policy), Some(saved));
        assert_eq!(
            c.newest(Weights::Policy)
                .map(|(v, p)| (v, read_weights(&p).ok())),
            Some((5, Some(b"five".to_vec())))
        );
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
