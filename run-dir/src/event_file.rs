//! TensorBoard event files: TFRecord framing around `Event` protobuf messages, as TensorFlow
//! defines them (`tensorflow/core/util/event.proto`, `tensorflow/core/framework/summary.proto`;
//! the framing in `tensorflow/core/lib/io/record_writer.cc`). Only what scalars need: the
//! first event names the file version, each later one carries a summary of tagged
//! `simple_value`s at a step. TensorBoard's own reader is the check
//! (`scripts/python/tensorboard_scalars.py`, `tests/services.rs`).
//!
//! A record is `length` (u64, little-endian), the masked CRC-32C of those 8 bytes (u32), the
//! data, and the masked CRC-32C of the data; masking is `rotate_right(15) + 0xa282ead8`.

use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;
#[cfg(test)]
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use prost::Message;

/// `tensorflow.Event`, the fields a scalar event file uses.
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(string, optional, tag = "3")]
    file_version: Option<String>,
    #[prost(message, optional, tag = "5")]
    summary: Option<Summary>,
}

/// `tensorflow.Summary`.
#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` with a `simple_value`.
#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(float, optional, tag = "2")]
    simple_value: Option<f32>,
}

/// What TensorBoard's reader expects in the first event.
const FILE_VERSION: &str = "brain.Event:2";

/// Files this process made, so that two in the same second get different names.
static FILES: AtomicU64 = AtomicU64::new(0);

fn masked_crc(bytes: &[u8]) -> u32 {
    crc32c::crc32c(bytes)
        .rotate_right(15)
        .wrapping_add(0xa282_ead8)
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// One event file being written.
#[derive(Debug)]
pub(crate) struct EventFile {
    out: BufWriter<File>,
    #[cfg(test)]
    path: PathBuf,
}

impl EventFile {
    /// A new file in `dir` (created if missing), named as TensorFlow names them
    /// (`events.out.tfevents.SECONDS.HOST.PID.N`), with its file-version event.
    pub(crate) fn create(dir: &Path) -> io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .map(|h| h.trim().to_string())
            .ok()
            .filter(|h| !h.is_empty() && !h.contains(['/', '\\']))
            .unwrap_or_else(|| "localhost".into());
        let name = format!(
            "events.out.tfevents.{}.{host}.{}.{}",
            now() as u64,
            std::process::id(),
            FILES.fetch_add(1, Ordering::Relaxed)
        );
        let path = dir.join(name);
        let mut file = Self {
            out: BufWriter::new(File::create(&path)?),
            #[cfg(test)]
            path,
        };
        file.write_event(&Event {
            wall_time: now(),
            step: 0,
            file_version: Some(FILE_VERSION.into()),
            summary: None,
        })?;
        file.out.flush()?;
        Ok(file)
    }

    /// The file's path.
    #[cfg(test)]
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one event of `scalars` (tag, value) at `step` and flushes it to the file.
    pub(crate) fn write_scalars(
        &mut self,
        step: u64,
        scalars: impl IntoIterator<Item = (String, f32)>,
    ) -> io::Result<()> {
        let value: Vec<SummaryValue> = scalars
            .into_iter()
            .map(|(tag, v)| SummaryValue {
                tag,
                simple_value: Some(v),
            })
            .collect();
        if value.is_empty() {
            return Ok(());
        }
        self.write_event(&Event {
            wall_time: now(),
            step: i64::try_from(step).unwrap_or(i64::MAX),
            file_version: None,
            summary: Some(Summary { value }),
        })?;
        self.out.flush()
    }

    fn write_event(&mut self, event: &Event) -> io::Result<()> {
        let data = event.encode_to_vec();
        let len = (data.len() as u64).to_le_bytes();
        self.out.write_all(&len)?;
        self.out.write_all(&masked_crc(&len).to_le_bytes())?;
        self.out.write_all(&data)?;
        self.out.write_all(&masked_crc(&data).to_le_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads the records back, checking both checksums of each.
    fn records(bytes: &[u8]) -> Vec<Event> {
        let mut out = Vec::new();
        let mut at = 0;
        while at < bytes.len() {
            let len: [u8; 8] = bytes[at..at + 8].try_into().expect("8 bytes");
            let crc = u32::from_le_bytes(bytes[at + 8..at + 12].try_into().expect("4 bytes"));
            assert_eq!(crc, masked_crc(&len));
            let n = u64::from_le_bytes(len) as usize;
            let data = &bytes[at + 12..at + 12 + n];
            let crc =
                u32::from_le_bytes(bytes[at + 12 + n..at + 16 + n].try_into().expect("4 bytes"));
            assert_eq!(crc, masked_crc(data));
            out.push(Event::decode(data).expect("an Event"));
            at += 16 + n;
        }
        out
    }

    #[test]
    fn the_masked_crc_is_tensorflows() {
        // CRC-32C("123456789") = 0xe3069283 (the standard check value), masked
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
        assert_eq!(
            masked_crc(b"123456789"),
            0xe306_9283u32.rotate_right(15).wrapping_add(0xa282_ead8)
        );
    }

    #[test]
    fn events_read_back_with_their_tags_steps_and_values() {
        let dir = std::env::temp_dir().join(format!("jsae-events-{}", std::process::id()));
        let mut file = EventFile::create(&dir).expect("creates");
        let other = EventFile::create(&dir).expect("creates a second");
        assert_ne!(file.path(), other.path(), "two files in one second differ");
        file.write_scalars(
            100,
            [("loss".to_string(), 0.5), ("eval/return".into(), -1.0)],
        )
        .expect("writes");
        file.write_scalars(200, []).expect("nothing to write");
        let events = records(&std::fs::read(file.path()).expect("reads"));
        std::fs::remove_dir_all(&dir).expect("removes");
        assert_eq!(events.len(), 2);
        assert_eq!(events[0].file_version.as_deref(), Some(FILE_VERSION));
        assert_eq!(events[1].step, 100);
        let values = &events[1].summary.as_ref().expect("a summary").value;
        let read: Vec<(&str, Option<f32>)> = values
            .iter()
            .map(|v| (v.tag.as_str(), v.simple_value))
            .collect();
        assert_eq!(read, [("loss", Some(0.5)), ("eval/return", Some(-1.0))]);
    }
}
