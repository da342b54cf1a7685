//! The messages exchanged by the JSAE-RL components, their gRPC form and their validation.
//!
//! The actor, the embedder and the learner own their state and talk only through the
//! messages defined here: [`TransitionBatch`] (actor -> embedder), [`RolloutFragment`]
//! (actor -> learner), [`EmbeddingSnapshot`] and [`PolicySnapshot`] (services -> actors),
//! and [`EvalReport`] (actor -> learner at the end of a run). In one-process mode they travel
//! as plain values; the gRPC transport wraps the same types (`proto/jsae.proto`).
//!
//! Layout: `messages` (the messages), `validate` (checks every receiver runs on input),
//! `grpc` (the generated gRPC code as [`pb`], conversions, snapshot chunking, size limits),
//! `codec` (the strict decoder every generated service uses), `status` (the one mapping of
//! refusals to gRPC codes), `client_end` (whether a client ended its stream or cancelled it), `random_id` (identifiers nobody can guess) and `catalogue_tag`
//! (the catalogue a recommender embedding's snapshot bytes are of). The spaces and
//! batches the messages carry come from `jsae_spaces` and are re-exported here.

#![forbid(unsafe_code)]

mod catalogue_tag;
mod client_end;
mod codec;
mod grpc;
mod messages;
mod random_id;
mod status;
mod validate;

pub use catalogue_tag::CatalogueTag;
pub use client_end::{ClientEnd, WatchesClientEnd};
pub use grpc::{
    Assembled, FILE_DESCRIPTOR_SET, MAX_MESSAGE_BYTES, MAX_SNAPSHOT_BYTES, Reassembler,
    SNAPSHOT_CHUNK, SnapshotChunks, chunk_snapshot, embedding_chunks, pb, policy_chunks,
};
pub use jsae_spaces::{ActionBatch, ActionSpace, StateBatch, StateSpace};
pub use messages::{
    EmbeddingSnapshot, EpisodeStat, EvalReport, PolicySnapshot, RolloutFragment, TransitionBatch,
};
pub use random_id::random_id;
pub use status::{RpcError, TooLargeIsExhausted, receive_error};
pub use validate::{
    FragmentBounds, MAX_ABS_POLICY_INPUT, ValidationError, check_episodes, validate_states,
};
