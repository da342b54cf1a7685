//! The gRPC form of the messages: the code generated from `proto/jsae.proto` (`pb`), the
//! conversions between it and the library types, snapshot chunking, and the message-size
//! limits every client and server sets.
//!
//! Conversions from the wire check structure only (a oneof that is present, sizes that fit);
//! receivers then run the `validate` checks against their spaces.

use crate::{
    ActionBatch, EmbeddingSnapshot, EpisodeStat, EvalReport, PolicySnapshot, RolloutFragment,
    StateBatch, TransitionBatch, ValidationError,
};

/// The generated messages, clients and servers of package `jsae.v1`.
#[allow(
    missing_docs,
    clippy::all,
    clippy::pedantic,
    missing_debug_implementations
)]
pub mod pb {
    tonic::include_proto!("jsae.v1");
}

/// The encoded file descriptor set of `jsae.proto`, for server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/jsae.fds"));

/// Largest encoded message a service or client accepts (16 MiB). Snapshots travel in chunks
/// of [`SNAPSHOT_CHUNK`] bytes, so only transition batches and fragments come near it.
pub const MAX_MESSAGE_BYTES: usize = 16 * 1024 * 1024;

/// Bytes of snapshot per chunk (256 KiB): what a watch stream holds of a snapshot at most,
/// beside the shared snapshot.
pub const SNAPSHOT_CHUNK: usize = 256 * 1024;

/// Largest snapshot a receiver reassembles (2 GiB): a recommender embedding of a million
/// items is 801 MB (phi's and g's tables), of two million 1.6 GB.
pub const MAX_SNAPSHOT_BYTES: u64 = 2 * 1024 * 1024 * 1024;

/// What a receiver reserves for a snapshot before its bytes arrive (64 MiB): beyond that the
/// buffer grows as they come, so a sender's claimed length alone takes no memory.
const SNAPSHOT_RESERVE: u64 = 64 * 1024 * 1024;

fn missing(field: &'static str) -> ValidationError {
    ValidationError::Missing { field }
}

// Library -> wire conversions take the value: the data moves into the message, no copy.

impl From<StateBatch> for pb::StateBatch {
    fn from(b: StateBatch) -> Self {
        use pb::state_batch::Kind;
        let kind = match b {
            StateBatch::Categorical { factors, data } => Kind::Categorical(pb::CategoricalStates {
                factors: factors as u32,
                data,
            }),
            StateBatch::Real { dim, data } => Kind::Real(pb::RealStates {
                dim: dim as u32,
                data,
            }),
        };
        Self { kind: Some(kind) }
    }
}

fn state_batch(
    field: &'static str,
    b: Option<pb::StateBatch>,
) -> Result<StateBatch, ValidationError> {
    use pb::state_batch::Kind;
    match b.and_then(|b| b.kind).ok_or(missing(field))? {
        Kind::Categorical(c) => Ok(StateBatch::Categorical {
            factors: c.factors as usize,
            data: c.data,
        }),
        Kind::Real(r) => Ok(StateBatch::Real {
            dim: r.dim as usize,
            data: r.data,
        }),
    }
}

impl From<ActionBatch> for pb::ActionBatch {
    fn from(b: ActionBatch) -> Self {
        use pb::action_batch::Kind;
        let kind = match b {
            ActionBatch::Discrete(data) => Kind::Discrete(pb::DiscreteActions { data }),
            ActionBatch::Continuous { dim, data } => Kind::Continuous(pb::ContinuousActions {
                dim: dim as u32,
                data,
            }),
        };
        Self { kind: Some(kind) }
    }
}

fn action_batch(
    field: &'static str,
    b: Option<pb::ActionBatch>,
) -> Result<ActionBatch, ValidationError> {
    use pb::action_batch::Kind;
    match b.and_then(|b| b.kind).ok_or(missing(field))? {
        Kind::Discrete(d) => Ok(ActionBatch::Discrete(d.data)),
        Kind::Continuous(c) => Ok(ActionBatch::Continuous {
            dim: c.dim as usize,
            data: c.data,
        }),
    }
}

impl From<TransitionBatch> for pb::TransitionBatch {
    fn from(t: TransitionBatch) -> Self {
        Self {
            actor_id: t.actor_id,
            states: Some(t.states.into()),
            actions: Some(t.actions.into()),
            rewards: t.rewards,
            next_states: Some(t.next_states.into()),
            terminated: t.terminated,
        }
    }
}

impl TryFrom<pb::TransitionBatch> for TransitionBatch {
    type Error = ValidationError;

    fn try_from(t: pb::TransitionBatch) -> Result<Self, Self::Error> {
        Ok(Self {
            actor_id: t.actor_id,
            states: state_batch("states", t.states)?,
            actions: action_batch("actions", t.actions)?,
            rewards: t.rewards,
            next_states: state_batch("next_states", t.next_states)?,
            terminated: t.terminated,
        })
    }
}

impl From<&EpisodeStat> for pb::EpisodeStat {
    fn from(e: &EpisodeStat) -> Self {
        Self {
            ret: e.ret,
            length: e.length,
            success: e.success,
        }
    }
}

fn episodes(list: Vec<pb::EpisodeStat>) -> Result<Vec<EpisodeStat>, ValidationError> {
    list.into_iter()
        .enumerate()
        .map(|(index, e)| {
            if e.ret.is_finite() {
                Ok(EpisodeStat {
                    ret: e.ret,
                    length: e.length,
                    success: e.success,
                })
            } else {
                Err(ValidationError::NotFinite {
                    field: "episodes.ret",
                    index,
                })
            }
        })
        .collect()
}

impl From<RolloutFragment> for pb::RolloutFragment {
    fn from(f: RolloutFragment) -> Self {
        Self {
            actor_id: f.actor_id,
            env_index: f.env_index,
            policy_version: f.policy_version,
            embedding_version: f.embedding_version,
            actor_env_steps: f.actor_env_steps,
            x_dim: f.x_dim as u32,
            x: f.x,
            actions: Some(f.actions.into()),
            logp: f.logp,
            rewards: f.rewards,
            terminated: f.terminated,
            truncated: f.truncated,
            truncated_next_x: f.truncated_next_x,
            last_next_x: f.last_next_x,
            episodes: f.episodes.iter().map(Into::into).collect(),
            actor_incarnation: f.actor_incarnation,
            visit_keys: f.visit_keys,
        }
    }
}

impl TryFrom<pb::RolloutFragment> for RolloutFragment {
    type Error = ValidationError;

    fn try_from(f: pb::RolloutFragment) -> Result<Self, Self::Error> {
        Ok(Self {
            actor_id: f.actor_id,
            env_index: f.env_index,
            policy_version: f.policy_version,
            embedding_version: f.embedding_version,
            actor_env_steps: f.actor_env_steps,
            x_dim: f.x_dim as usize,
            x: f.x,
            actions: action_batch("actions", f.actions)?,
            logp: f.logp,
            rewards: f.rewards,
            terminated: f.terminated,
            truncated: f.truncated,
            truncated_next_x: f.truncated_next_x,
            last_next_x: f.last_next_x,
            episodes: episodes(f.episodes)?,
            actor_incarnation: f.actor_incarnation,
            visit_keys: f.visit_keys,
        })
    }
}

impl EvalReport {
    /// The wire form, answering request `request_id` from actor `actor_id`.
    pub fn to_wire(&self, actor_id: u64, request_id: u64) -> pb::EvalReport {
        pb::EvalReport {
            actor_id,
            policy_version: self.policy_version,
            embedding_version: self.embedding_version,
            episodes: self.episodes.iter().map(Into::into).collect(),
            request_id,
            stochastic_episodes: self.stochastic.iter().map(Into::into).collect(),
        }
    }

    /// From the wire form (with its request id).
    pub fn from_wire(r: pb::EvalReport) -> Result<(Self, u64), ValidationError> {
        if r.episodes.is_empty() {
            return Err(missing("episodes"));
        }
        Ok((
            Self {
                policy_version: r.policy_version,
                embedding_version: r.embedding_version,
                episodes: episodes(r.episodes)?,
                stochastic: episodes(r.stochastic_episodes)?,
            },
            r.request_id,
        ))
    }
}

/// A snapshot's chunks of at most [`SNAPSHOT_CHUNK`] bytes (one empty chunk for empty
/// bytes), the losses and the structure measure on every chunk, cut one at a time as they
/// are taken: a stream that sends them holds the shared snapshot and one chunk, never a copy
/// of the whole.
pub struct SnapshotChunks<S> {
    snapshot: std::sync::Arc<S>,
    bytes: fn(&S) -> &[u8],
    header: pb::SnapshotChunk,
    offset: usize,
    done: bool,
}

impl<S> std::fmt::Debug for SnapshotChunks<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SnapshotChunks")
            .field("version", &self.header.version)
            .field("total_len", &self.header.total_len)
            .field("offset", &self.offset)
            .finish()
    }
}

impl<S> Iterator for SnapshotChunks<S> {
    type Item = pb::SnapshotChunk;

    fn next(&mut self) -> Option<pb::SnapshotChunk> {
        if self.done {
            return None;
        }
        let bytes = (self.bytes)(&self.snapshot);
        let end = (self.offset + SNAPSHOT_CHUNK).min(bytes.len());
        let chunk = pb::SnapshotChunk {
            offset: self.offset as u64,
            data: bytes[self.offset..end].to_vec(),
            last: end == bytes.len(),
            ..self.header.clone()
        };
        self.offset = end;
        self.done = chunk.last;
        Some(chunk)
    }
}

impl<S> SnapshotChunks<S> {
    /// The chunks of `bytes(snapshot)`, each with `header`'s version, losses and structure.
    fn new(snapshot: std::sync::Arc<S>, bytes: fn(&S) -> &[u8], header: pb::SnapshotChunk) -> Self {
        let total_len = bytes(&snapshot).len() as u64;
        Self {
            snapshot,
            bytes,
            header: pb::SnapshotChunk {
                total_len,
                ..header
            },
            offset: 0,
            done: false,
        }
    }
}

/// Splits a snapshot's bytes into chunks (all at once; a stream takes them one at a time
/// from [`SnapshotChunks`]).
pub fn chunk_snapshot(
    version: u64,
    bytes: &[u8],
    model_loss: f32,
    decoder_loss: f32,
    action_structure: Option<f32>,
) -> Vec<pb::SnapshotChunk> {
    let header = pb::SnapshotChunk {
        version,
        model_loss,
        decoder_loss,
        action_structure,
        ..Default::default()
    };
    SnapshotChunks::new(std::sync::Arc::new(bytes.to_vec()), Vec::as_slice, header).collect()
}

/// The chunks of a shared embedding snapshot, cut as they are taken.
pub fn embedding_chunks(s: std::sync::Arc<EmbeddingSnapshot>) -> SnapshotChunks<EmbeddingSnapshot> {
    let header = pb::SnapshotChunk {
        version: s.version,
        model_loss: s.model_loss,
        decoder_loss: s.decoder_loss,
        action_structure: s.action_structure,
        ..Default::default()
    };
    SnapshotChunks::new(s, |s| &s.bytes, header)
}

/// The chunks of a shared policy snapshot, cut as they are taken.
pub fn policy_chunks(s: std::sync::Arc<PolicySnapshot>) -> SnapshotChunks<PolicySnapshot> {
    let header = pb::SnapshotChunk {
        version: s.version,
        ..Default::default()
    };
    SnapshotChunks::new(s, |s| &s.bytes, header)
}

/// Reassembles snapshots from a stream of chunks; a chunk out of order or of another version
/// than the one under way is an error, and so is a snapshot above [`MAX_SNAPSHOT_BYTES`].
#[derive(Debug, Default)]
pub struct Reassembler {
    version: u64,
    total_len: u64,
    bytes: Vec<u8>,
}

/// A complete snapshot from a [`Reassembler`].
#[derive(Debug, Clone, PartialEq)]
pub struct Assembled {
    /// Its version.
    pub version: u64,
    /// Its bytes.
    pub bytes: Vec<u8>,
    /// Model loss (embedding snapshots).
    pub model_loss: f32,
    /// Decoder loss (embedding snapshots).
    pub decoder_loss: f32,
    /// Action-embedding structure (embedding snapshots, where measured).
    pub action_structure: Option<f32>,
}

impl Assembled {
    /// As an embedding snapshot.
    pub fn into_embedding(self) -> EmbeddingSnapshot {
        EmbeddingSnapshot {
            version: self.version,
            bytes: self.bytes,
            model_loss: self.model_loss,
            decoder_loss: self.decoder_loss,
            action_structure: self.action_structure,
        }
    }

    /// As a policy snapshot.
    pub fn into_policy(self) -> PolicySnapshot {
        PolicySnapshot {
            version: self.version,
            bytes: self.bytes,
        }
    }
}

impl Reassembler {
    /// Takes one chunk; returns the snapshot when `chunk` completes it.
    pub fn push(&mut self, chunk: pb::SnapshotChunk) -> Result<Option<Assembled>, ValidationError> {
        if chunk.total_len > MAX_SNAPSHOT_BYTES {
            return Err(ValidationError::TooLarge {
                field: "snapshot",
                limit: MAX_SNAPSHOT_BYTES as usize,
                got: chunk.total_len as usize,
            });
        }
        if chunk.offset == 0 {
            self.version = chunk.version;
            self.total_len = chunk.total_len;
            self.bytes = Vec::with_capacity(chunk.total_len.min(SNAPSHOT_RESERVE) as usize);
        } else if chunk.version != self.version || chunk.offset != self.bytes.len() as u64 {
            return Err(ValidationError::Sequence { field: "snapshot" });
        }
        self.bytes.extend_from_slice(&chunk.data);
        if self.bytes.len() as u64 > self.total_len {
            return Err(ValidationError::Sequence { field: "snapshot" });
        }
        if !chunk.last {
            return Ok(None);
        }
        if self.bytes.len() as u64 != self.total_len {
            return Err(ValidationError::Sequence { field: "snapshot" });
        }
        Ok(Some(Assembled {
            version: self.version,
            bytes: std::mem::take(&mut self.bytes),
            model_loss: chunk.model_loss,
            decoder_loss: chunk.decoder_loss,
            action_structure: chunk.action_structure.filter(|v| v.is_finite()),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snapshots_survive_chunking() {
        for len in [
            0,
            1,
            SNAPSHOT_CHUNK,
            SNAPSHOT_CHUNK + 1,
            3 * SNAPSHOT_CHUNK - 7,
        ] {
            let bytes: Vec<u8> = (0..len).map(|i| (i * 31 % 251) as u8).collect();
            let mut r = Reassembler::default();
            let mut done = None;
            for c in chunk_snapshot(9, &bytes, 0.5, 0.25, Some(0.4)) {
                assert!(done.is_none(), "a chunk after the last one");
                done = r.push(c).expect("in order");
            }
            let a = done.expect("complete");
            assert_eq!((a.version, a.bytes, a.model_loss), (9, bytes, 0.5));
            assert_eq!(a.action_structure, Some(0.4));
        }
    }

    #[test]
    fn a_claimed_length_takes_no_memory_and_one_over_the_limit_is_refused() {
        let chunk = |total_len| pb::SnapshotChunk {
            version: 1,
            total_len,
            data: vec![0; 8],
            ..Default::default()
        };
        let mut r = Reassembler::default();
        assert_eq!(r.push(chunk(MAX_SNAPSHOT_BYTES)), Ok(None));
        assert!(r.bytes.capacity() as u64 <= SNAPSHOT_RESERVE);
        assert!(r.push(chunk(MAX_SNAPSHOT_BYTES + 1)).is_err());
    }

    #[test]
    fn out_of_order_chunks_are_refused() {
        let bytes = vec![1u8; SNAPSHOT_CHUNK * 2 + 1];
        let chunks = chunk_snapshot(3, &bytes, 0.0, 0.0, None);
        let mut r = Reassembler::default();
        assert_eq!(r.push(chunks[0].clone()), Ok(None));
        assert!(r.push(chunks[2].clone()).is_err());
    }

    #[test]
    fn batches_round_trip_and_missing_parts_are_named() {
        let t = TransitionBatch {
            actor_id: 4,
            states: StateBatch::Real {
                dim: 2,
                data: vec![0.1, 0.2],
            },
            actions: ActionBatch::Discrete(vec![3]),
            rewards: vec![-0.01],
            next_states: StateBatch::Real {
                dim: 2,
                data: vec![0.3, 0.4],
            },
            terminated: vec![false],
        };
        let w = pb::TransitionBatch::from(t.clone());
        assert_eq!(TransitionBatch::try_from(w.clone()), Ok(t));
        let mut w = w;
        w.actions = None;
        assert_eq!(
            TransitionBatch::try_from(w),
            Err(ValidationError::Missing { field: "actions" })
        );
    }
}
