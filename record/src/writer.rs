//! The [`Recorder`]: transitions into an MCAP file, one protobuf message each.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use jsae_wire::{ActionBatch, StateBatch, TransitionBatch};
use mcap::records::MessageHeader;
use prost::Message;

use crate::{RecordError, RecordingInfo, SCHEMA_NAME, TOPIC, TRANSITION_SCHEMA, pb};

/// A chunk is closed once this many uncompressed bytes are in it.
const CHUNK_BYTES: u64 = 1 << 20;
/// ... or once it has been open this long: what a crash can lose at most.
pub const FLUSH_EVERY: Duration = Duration::from_secs(2);

/// What a transition batch does not say about its rows, row for row: where in which episode
/// each step was taken, whether it was cut, and the weights that chose it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecordedSteps {
    /// The policy version that acted (0: random play).
    pub policy_version: u64,
    /// The embedding version that acted (0: none).
    pub embedding_version: u64,
    /// The environment within the actor's vector.
    pub env_index: Vec<u32>,
    /// Episodes that environment started before this one.
    pub episode: Vec<u64>,
    /// The step within the episode, from 0.
    pub step: Vec<u32>,
    /// Whether the episode was cut (a time limit) at this step.
    pub truncated: Vec<bool>,
}

impl RecordedSteps {
    /// Empties the rows, keeping the allocations.
    pub fn clear(&mut self) {
        self.env_index.clear();
        self.episode.clear();
        self.step.clear();
        self.truncated.clear();
    }

    /// Rows held.
    pub fn len(&self) -> usize {
        self.env_index.len()
    }

    /// Whether no row is held.
    pub fn is_empty(&self) -> bool {
        self.env_index.is_empty()
    }
}

/// Writes transitions into an MCAP file; [`Recorder::finish`] writes the summary (dropped
/// without it, the file still reads up to its last closed chunk).
pub struct Recorder {
    writer: mcap::Writer<BufWriter<File>>,
    channel: u16,
    sequence: u32,
    /// The message each transition is written from: the run id set once, the rows' vectors
    /// emptied and refilled (no allocation per transition).
    message: pb::Transition,
    path: PathBuf,
    written: u64,
    opened: Instant,
    buf: Vec<u8>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path)
            .field("written", &self.written)
            .finish()
    }
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

fn state_row(batch: &StateBatch, i: usize, real: &mut Vec<f32>, categories: &mut Vec<u32>) {
    match batch {
        StateBatch::Real { dim, data } => real.extend_from_slice(&data[i * dim..(i + 1) * dim]),
        StateBatch::Categorical { factors, data } => {
            categories.extend_from_slice(&data[i * factors..(i + 1) * factors]);
        }
    }
}

impl Recorder {
    /// Creates (or replaces) `path`, and the folders above it, and writes the schema and the channel describing `info`.
    pub fn create(path: &Path, info: &RecordingInfo) -> Result<Self, RecordError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(RecordError::io(path))?;
        }
        let file = File::create(path).map_err(RecordError::io(path))?;
        let mut writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(CHUNK_BYTES))
            // compress on the stepping thread: worker threads would take cores from training
            .compression_threads(0)
            .profile("")
            .library(concat!("jsae-record ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(RecordError::mcap(path))?;
        let schema = writer
            .add_schema(SCHEMA_NAME, "protobuf", TRANSITION_SCHEMA)
            .map_err(RecordError::mcap(path))?;
        let channel = writer
            .add_channel(schema, TOPIC, "protobuf", &info.to_metadata())
            .map_err(RecordError::mcap(path))?;
        Ok(Self {
            writer,
            channel,
            sequence: 0,
            message: pb::Transition {
                run_id: info.run_id.clone(),
                ..Default::default()
            },
            path: path.to_path_buf(),
            written: 0,
            opened: Instant::now(),
            buf: Vec::new(),
        })
    }

    /// The file written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Transitions written so far.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Appends every row of `transitions` (with `steps`' row of the same index), then closes
    /// the chunk if it has been open for [`FLUSH_EVERY`].
    pub fn write(
        &mut self,
        transitions: &TransitionBatch,
        steps: &RecordedSteps,
    ) -> Result<(), RecordError> {
        let n = transitions.len();
        if steps.len() != n {
            return Err(RecordError::format(
                &self.path,
                format!("{n} transitions but {} step rows", steps.len()),
            ));
        }
        let time = now_ns();
        for i in 0..n {
            let m = &mut self.message;
            m.actor_id = transitions.actor_id;
            m.env_index = steps.env_index[i];
            m.episode = steps.episode[i];
            m.step = steps.step[i];
            m.reward = transitions.rewards[i];
            m.terminated = transitions.terminated[i];
            m.truncated = steps.truncated[i];
            m.policy_version = steps.policy_version;
            m.embedding_version = steps.embedding_version;
            for v in [&mut m.state, &mut m.next_state, &mut m.continuous_action] {
                v.clear();
            }
            m.state_categories.clear();
            m.next_state_categories.clear();
            state_row(
                &transitions.states,
                i,
                &mut m.state,
                &mut m.state_categories,
            );
            state_row(
                &transitions.next_states,
                i,
                &mut m.next_state,
                &mut m.next_state_categories,
            );
            m.discrete_action = None;
            match &transitions.actions {
                ActionBatch::Discrete(a) => m.discrete_action = Some(a[i]),
                ActionBatch::Continuous { dim, data } => m
                    .continuous_action
                    .extend_from_slice(&data[i * dim..(i + 1) * dim]),
            }
            self.buf.clear();
            self.message
                .encode(&mut self.buf)
                .map_err(|e| RecordError::format(&self.path, e.to_string()))?;
            let header = MessageHeader {
                channel_id: self.channel,
                sequence: self.sequence,
                log_time: time,
                publish_time: time,
            };
            self.writer
                .write_to_known_channel(&header, &self.buf)
                .map_err(RecordError::mcap(&self.path))?;
            self.sequence = self.sequence.wrapping_add(1);
            self.written += 1;
        }
        if self.opened.elapsed() >= FLUSH_EVERY {
            self.flush()?;
        }
        Ok(())
    }

    /// Closes the open chunk and hands it to the file.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.writer.flush().map_err(RecordError::mcap(&self.path))?;
        self.opened = Instant::now();
        Ok(())
    }

    /// Writes the last chunk, the summary and the footer; returns the transitions written.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        self.writer
            .finish()
            .map_err(RecordError::mcap(&self.path))?;
        let file = self
            .writer
            .into_inner()
            .into_inner()
            .map_err(|e| RecordError::io(&self.path)(e.into_error()))?;
        file.sync_all().map_err(RecordError::io(&self.path))?;
        Ok(self.written)
    }
}
