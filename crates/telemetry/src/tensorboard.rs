//! TensorBoard event files: scalars a run's processes append while they run, so
//! `tensorboard --logdir runs` shows a live cluster.
//!
//! Format (TensorFlow's `tensorflow/core/util/event.proto`, `summary.proto` and
//! `tensorflow/core/lib/io/record_writer.cc`): a file named `events.out.tfevents.<unix seconds>
//! .<host>.<pid>.<label>` holding TFRecords — `u64` little-endian length, the masked CRC-32C of
//! those 8 bytes, the payload, the masked CRC-32C of the payload — whose payloads are `Event`
//! protobufs: first one with `file_version = "brain.Event:2"`, then one per step with a `Summary`
//! of `simple_value` scalars. Each event is flushed to the file as it is written, so a killed
//! writer leaves every complete record readable (TensorBoard stops at a torn last record).

use std::{
    fs::{File, OpenOptions},
    io::{BufWriter, Write as _},
    path::{Path, PathBuf},
};

use prost::Message as _;

use crate::{Result, TelemetryError};

/// `tensorflow.Event` (the fields written here).
#[derive(Clone, PartialEq, prost::Message)]
struct Event {
    /// Seconds since the Unix epoch.
    #[prost(double, tag = "1")]
    wall_time: f64,
    #[prost(int64, tag = "2")]
    step: i64,
    #[prost(oneof = "What", tags = "3, 5")]
    what: Option<What>,
}

#[derive(Clone, PartialEq, prost::Oneof)]
enum What {
    #[prost(string, tag = "3")]
    FileVersion(String),
    #[prost(message, tag = "5")]
    Summary(Summary),
}

/// `tensorflow.Summary`.
#[derive(Clone, PartialEq, prost::Message)]
struct Summary {
    #[prost(message, repeated, tag = "1")]
    value: Vec<SummaryValue>,
}

/// `tensorflow.Summary.Value` with its `simple_value` member (a oneof, so 0.0 is still written).
#[derive(Clone, PartialEq, prost::Message)]
struct SummaryValue {
    #[prost(string, tag = "1")]
    tag: String,
    #[prost(oneof = "ValueKind", tags = "2")]
    value: Option<ValueKind>,
}

#[derive(Clone, PartialEq, prost::Oneof)]
enum ValueKind {
    #[prost(float, tag = "2")]
    SimpleValue(f32),
}

const CASTAGNOLI: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);

/// TFRecord's masked CRC-32C (`tensorflow/core/lib/hash/crc32c.h`, `Mask`).
fn masked_crc(bytes: &[u8]) -> u32 {
    let c = CASTAGNOLI.checksum(bytes);
    c.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// One TFRecord around `payload`.
fn record(payload: &[u8], out: &mut Vec<u8>) {
    let len = (payload.len() as u64).to_le_bytes();
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&masked_crc(payload).to_le_bytes());
}

/// Appends scalar summaries to a new TensorBoard event file (see the module docs).
#[derive(Debug)]
pub struct EventWriter {
    path: PathBuf,
    file: BufWriter<File>,
    buf: Vec<u8>,
    events: u64,
}

impl EventWriter {
    /// Creates `dir/events.out.tfevents.<seconds>.<host>.<pid>.<label>` (and `dir`), writes the
    /// file-version event and flushes. `label` names the writer (`learner`, `evaluator`): two
    /// processes writing into one folder never share a file.
    ///
    /// # Errors
    /// [`TelemetryError::Io`] when the folder or file cannot be created or written.
    pub fn create(dir: &Path, label: &str) -> Result<Self> {
        let io_err = |path: &Path| {
            let path = path.to_owned();
            move |source| TelemetryError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        let host = nix::unistd::gethostname()
            .ok()
            .and_then(|h| h.into_string().ok())
            .filter(|h| !h.is_empty() && !h.contains('/'))
            .unwrap_or_else(|| "localhost".into());
        let label: String = label
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let stem = format!(
            "events.out.tfevents.{:010}.{host}.{}.{label}",
            now.as_secs(),
            std::process::id()
        );
        // A second writer of the same label in the same second and process gets `.1`, `.2`, ...
        let mut n = 0u32;
        let (path, file) = loop {
            let path = if n == 0 {
                dir.join(&stem)
            } else {
                dir.join(format!("{stem}.{n}"))
            };
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(file) => break (path, file),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists && n < 1000 => n += 1,
                Err(e) => return Err(io_err(&path)(e)),
            }
        };
        let mut w = Self {
            path,
            file: BufWriter::new(file),
            buf: Vec::new(),
            events: 0,
        };
        w.write_event(&Event {
            wall_time: now.as_secs_f64(),
            step: 0,
            what: Some(What::FileVersion("brain.Event:2".into())),
        })?;
        w.flush()?;
        Ok(w)
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Events written (the file-version event included).
    pub fn events(&self) -> u64 {
        self.events
    }

    /// Writes one event at `step` (TensorBoard's x axis; terl uses env steps) holding every
    /// `(tag, value)` as a scalar (f32, as TensorBoard stores them; non-finite values are
    /// kept), stamped `unix_seconds`, and flushes it to the file. Empty `values` write nothing.
    ///
    /// # Errors
    /// [`TelemetryError::Io`] when the file cannot be written.
    pub fn scalars<'a>(
        &mut self,
        step: u64,
        unix_seconds: f64,
        values: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<()> {
        let value: Vec<SummaryValue> = values
            .into_iter()
            .map(|(tag, v)| SummaryValue {
                tag: tag.to_owned(),
                value: Some(ValueKind::SimpleValue(v as f32)),
            })
            .collect();
        if value.is_empty() {
            return Ok(());
        }
        self.write_event(&Event {
            wall_time: unix_seconds,
            step: i64::try_from(step).unwrap_or(i64::MAX),
            what: Some(What::Summary(Summary { value })),
        })?;
        self.flush()
    }

    fn write_event(&mut self, event: &Event) -> Result<()> {
        let payload = event.encode_to_vec();
        self.buf.clear();
        record(&payload, &mut self.buf);
        self.file
            .write_all(&self.buf)
            .map_err(|source| TelemetryError::Io {
                path: self.path.clone(),
                source,
            })?;
        self.events += 1;
        Ok(())
    }

    /// Pushes buffered events to the file.
    ///
    /// # Errors
    /// [`TelemetryError::Io`] when the file cannot be written.
    pub fn flush(&mut self) -> Result<()> {
        self.file.flush().map_err(|source| TelemetryError::Io {
            path: self.path.clone(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_and_its_mask_match_known_values() {
        // CRC-32C check value (RFC 3720, "123456789"), and TensorFlow's mask of it,
        // ((c >> 15) | (c << 17)) + 0xa282ead8 mod 2^32, computed by hand (Python).
        assert_eq!(CASTAGNOLI.checksum(b"123456789"), 0xE306_9283);
        assert_eq!(masked_crc(b"123456789"), 0xC78A_B0E5);
    }

    #[test]
    fn a_zero_scalar_is_still_encoded() {
        let v = SummaryValue {
            tag: "a".into(),
            value: Some(ValueKind::SimpleValue(0.0)),
        };
        // tag (1: "a") and simple_value (2: fixed32 0.0): 3 + 5 bytes.
        assert_eq!(v.encode_to_vec(), vec![0x0a, 1, b'a', 0x15, 0, 0, 0, 0]);
    }
}
