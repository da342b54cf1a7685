//! The latest-checkpoint file (`KIND-latest.ckpt`): one file that carries its checkpoint's
//! version, the weights, an optional training state (the learner's optimiser moments, reward
//! scaler and counters; empty for the embedder) and a CRC-32 of all of it, so that a torn or
//! damaged file is told apart from a good one and a version can never name other weights.
//!
//! ```text
//! offset      size  field (integers little-endian)
//! 0           8     magic "JSAECKPT"
//! 8           4     format, u32 (1)
//! 12          8     version, u64
//! 20          8     weights length W, u64
//! 28          8     state length S, u64
//! 36          W     weights (burnpack bytes, as the snapshots carry them)
//! 36 + W      S     training state
//! 36 + W + S  4     CRC-32 (IEEE) of every byte before it, u32
//! ```

use std::io::{self, Read};
use std::path::Path;

/// The first bytes of every latest-checkpoint file.
const MAGIC: &[u8; 8] = b"JSAECKPT";
/// The layout above.
const FORMAT: u32 = 1;
/// Bytes before the weights.
const HEADER: usize = 36;
/// Bytes after the state (the checksum).
const TRAILER: usize = 4;

/// One checkpoint as the latest file holds it.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct LatestCheckpoint {
    /// The weights' version (the policy's update count, the embedding's snapshot number).
    pub version: u64,
    /// The weights, as a snapshot carries them.
    pub weights: Vec<u8>,
    /// What training needs besides the weights to go on where it stopped (the learner's;
    /// empty where there is none). Opaque here: its writer reads it back.
    pub state: Vec<u8>,
}

/// Why a file is not a good latest checkpoint.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CheckpointFileError {
    /// The file does not start with the magic bytes.
    #[error("not a checkpoint file (no JSAECKPT header)")]
    NotACheckpoint,
    /// Written in a layout this build does not read.
    #[error("checkpoint format {0}; this build reads format {FORMAT}")]
    Format(u32),
    /// Shorter or longer than its header says (a torn write).
    #[error("{got} bytes where the header says {want}")]
    Length {
        /// The length the header gives.
        want: u64,
        /// The file's length.
        got: u64,
    },
    /// The bytes are not the ones written.
    #[error("checksum {computed:08x} where the file says {stored:08x}: the file is damaged")]
    Checksum {
        /// The checksum stored in the file.
        stored: u32,
        /// The checksum of its bytes.
        computed: u32,
    },
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    let mut b = [0; 4];
    b.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(b)
}

fn u64_at(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(b)
}

/// The header's format and version, checked for the magic bytes and the format.
fn header(bytes: &[u8]) -> Result<u64, CheckpointFileError> {
    if bytes.len() < HEADER || &bytes[..8] != MAGIC {
        return Err(CheckpointFileError::NotACheckpoint);
    }
    match u32_at(bytes, 8) {
        FORMAT => Ok(u64_at(bytes, 12)),
        other => Err(CheckpointFileError::Format(other)),
    }
}

impl LatestCheckpoint {
    /// The CRC-32 of the training state alone: what a resumed process logs, so that a test
    /// (or an operator) can tell it took up exactly the state a killed one saved.
    pub fn state_checksum(&self) -> u32 {
        crc32fast::hash(&self.state)
    }

    /// The file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(HEADER + self.weights.len() + self.state.len() + TRAILER);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&FORMAT.to_le_bytes());
        out.extend_from_slice(&self.version.to_le_bytes());
        out.extend_from_slice(&(self.weights.len() as u64).to_le_bytes());
        out.extend_from_slice(&(self.state.len() as u64).to_le_bytes());
        out.extend_from_slice(&self.weights);
        out.extend_from_slice(&self.state);
        let crc = crc32fast::hash(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    /// Reads [`Self::encode`]'s bytes: the header, the lengths and the checksum checked.
    pub fn decode(bytes: &[u8]) -> Result<Self, CheckpointFileError> {
        let version = header(bytes)?;
        let (w, s) = (u64_at(bytes, 20), u64_at(bytes, 28));
        let want = w
            .checked_add(s)
            .and_then(|n| n.checked_add((HEADER + TRAILER) as u64));
        let got = bytes.len() as u64;
        if want != Some(got) {
            return Err(CheckpointFileError::Length {
                want: want.unwrap_or(u64::MAX),
                got,
            });
        }
        let body = bytes.len() - TRAILER;
        let (stored, computed) = (u32_at(bytes, body), crc32fast::hash(&bytes[..body]));
        if stored != computed {
            return Err(CheckpointFileError::Checksum { stored, computed });
        }
        let weights_end = HEADER + w as usize;
        Ok(Self {
            version,
            weights: bytes[HEADER..weights_end].to_vec(),
            state: bytes[weights_end..body].to_vec(),
        })
    }
}

/// The version a latest-checkpoint file's header gives, read without the rest of the file
/// (its checksum is checked when the file is read: [`read_weights`]).
pub fn peek_version(path: &Path) -> io::Result<u64> {
    let mut head = [0; HEADER];
    std::fs::File::open(path)?.read_exact(&mut head)?;
    header(&head).map_err(io::Error::other)
}

/// The weights in a checkpoint file: a latest-checkpoint file is checked and unwrapped
/// (an error where it is damaged); any other file (`KIND-vN.bpk`, a file named by hand) is
/// the weights as written.
pub fn read_weights(path: &Path) -> io::Result<Vec<u8>> {
    let bytes = std::fs::read(path)?;
    if !bytes.starts_with(MAGIC) {
        return Ok(bytes);
    }
    LatestCheckpoint::decode(&bytes)
        .map(|c| c.weights)
        .map_err(|e| io::Error::other(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> LatestCheckpoint {
        LatestCheckpoint {
            version: 42,
            weights: (0..300u32).map(|i| (i * 7 % 251) as u8).collect(),
            state: vec![9, 8, 7],
        }
    }

    #[test]
    fn a_checkpoint_round_trips_and_any_flipped_byte_is_refused() {
        let bytes = sample().encode();
        assert_eq!(LatestCheckpoint::decode(&bytes), Ok(sample()));
        for at in [0, 9, 13, 21, 40, 200, bytes.len() - 2, bytes.len() - 1] {
            let mut bad = bytes.clone();
            bad[at] ^= 0x10;
            assert!(LatestCheckpoint::decode(&bad).is_err(), "byte {at} flipped");
        }
        let torn = &bytes[..bytes.len() - 10];
        assert!(matches!(
            LatestCheckpoint::decode(torn),
            Err(CheckpointFileError::Length { .. })
        ));
        assert_eq!(
            LatestCheckpoint::decode(b"plain burnpack bytes, no header"),
            Err(CheckpointFileError::NotACheckpoint)
        );
    }

    #[test]
    fn read_weights_unwraps_a_checkpoint_and_passes_other_files_through() {
        let dir = std::env::temp_dir().join(format!("jsae-ckpt-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let (wrapped, plain) = (dir.join("latest.ckpt"), dir.join("v1.bpk"));
        std::fs::write(&wrapped, sample().encode()).expect("write");
        std::fs::write(&plain, b"raw").expect("write");
        assert_eq!(read_weights(&wrapped).expect("reads"), sample().weights);
        assert_eq!(peek_version(&wrapped).expect("header"), 42);
        assert_eq!(read_weights(&plain).expect("reads"), b"raw".to_vec());
        let mut bad = sample().encode();
        bad[HEADER + 5] ^= 1;
        std::fs::write(&wrapped, bad).expect("write");
        let e = read_weights(&wrapped).expect_err("damaged");
        assert!(e.to_string().contains("checksum"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
