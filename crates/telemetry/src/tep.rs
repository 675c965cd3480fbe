//! [`TepDatasetWriter`] and [`read_tep_dataset`]: the TEP dataset as MCAP (layout and crash
//! recovery in the crate docs).

use std::{fmt, path::Path};

use prost::Message as _;
use terl_wire::{pb, TepSample};

use crate::log::{read_channel, Channel, ProtoWriter};
use crate::Result;

/// Topic of the TEP samples.
pub const TEP_TOPIC: &str = "/tep/samples";
/// Schema name (the protobuf message's full name) of the TEP samples.
pub const TEP_SCHEMA_NAME: &str = "terl.v1.TepSample";

const CHANNEL: Channel = Channel {
    topic: TEP_TOPIC,
    schema: TEP_SCHEMA_NAME,
    what: "TEP dataset",
};

/// Appends `terl.v1.TepSample` messages to an MCAP file (one schema, one channel, topic
/// [`TEP_TOPIC`]).
///
/// [`create`](Self::create) never overwrites an existing file and [`replace`](Self::replace)
/// starts the file over; appending to an existing dataset is not supported (a resumed run starts a
/// new file). Call [`flush`](Self::flush) at points you want to survive a crash and
/// [`finish`](Self::finish) at the end; dropping an unfinished writer finishes it too, logging
/// errors instead of returning them.
pub struct TepDatasetWriter {
    inner: ProtoWriter,
}

impl fmt::Debug for TepDatasetWriter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TepDatasetWriter")
            .field("path", &self.inner.path())
            .field("finished", &self.inner.is_finished())
            .field("messages", &self.inner.messages())
            .finish_non_exhaustive()
    }
}

impl TepDatasetWriter {
    /// Creates a new dataset at `path` (and its parent directories). Fails with
    /// [`crate::TelemetryError::AlreadyExists`] if the file exists.
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        Ok(Self {
            inner: ProtoWriter::open(path.as_ref(), CHANNEL, false)?,
        })
    }

    /// Creates the dataset at `path` (and its parent directories), discarding any file there.
    pub fn replace(path: impl AsRef<Path>) -> Result<Self> {
        Ok(Self {
            inner: ProtoWriter::open(path.as_ref(), CHANNEL, true)?,
        })
    }

    /// Path of the file being written.
    pub fn path(&self) -> &Path {
        self.inner.path()
    }

    /// Messages written so far.
    pub fn messages(&self) -> u64 {
        self.inner.messages()
    }

    /// Appends one sample; `log_time_ns` becomes the message's log and publish time (nanoseconds,
    /// by convention since the Unix epoch).
    pub fn write(&mut self, sample: &TepSample, log_time_ns: u64) -> Result<()> {
        self.inner.write(&pb::TepSample::from(sample), log_time_ns)
    }

    /// Closes the current chunk and hands everything written so far to the operating system:
    /// from now on a crash or kill of this process cannot lose those samples.
    pub fn flush(&mut self) -> Result<()> {
        self.inner.flush()
    }

    /// Writes the summary and footer, syncs the file to disk and returns the number of messages.
    pub fn finish(mut self) -> Result<u64> {
        self.inner.finish()
    }
}

/// The samples of a TEP dataset file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TepDataset {
    /// Valid samples, in file order.
    pub samples: Vec<TepSample>,
    /// Messages on [`TEP_TOPIC`] that did not decode or failed validation (skipped).
    pub rejected: u64,
    /// The file ended early or is damaged part-way (its writer was killed, the file was cut, a
    /// record length or a chunk is damaged): `samples` holds what was complete before that point.
    pub truncated: bool,
    /// Why reading stopped, in words: `Some` exactly when `truncated` is set.
    pub truncation: Option<String>,
}

/// Reads every sample on [`TEP_TOPIC`] of the MCAP file at `path`.
///
/// The file is read front to back (see the crate docs): messages are decoded with prost and
/// validated with `TryFrom<pb::TepSample>`; invalid ones are counted in
/// [`TepDataset::rejected`] and skipped with one warning. A file that ends early or breaks off
/// (a killed writer) or is damaged part-way (a damaged record length, a flipped byte in a chunk)
/// yields the complete chunks before that point with [`TepDataset::truncated`] set and the
/// reason in [`TepDataset::truncation`]; no length read from the file is trusted beyond the
/// file's size, so damage never makes the reader allocate more than the file holds. Errors: the
/// file cannot be read, is not MCAP, has no [`TEP_TOPIC`] channel, or that channel's schema or
/// encoding is not `terl.v1.TepSample` / protobuf.
pub fn read_tep_dataset(path: impl AsRef<Path>) -> Result<TepDataset> {
    let read = read_channel(path.as_ref(), CHANNEL, |bytes| {
        pb::TepSample::decode(bytes)
            .map_err(|e| format!("protobuf decode failed: {e}"))
            .and_then(|m| TepSample::try_from(m).map_err(|s| s.message().to_owned()))
    })?;
    Ok(TepDataset {
        samples: read.items,
        rejected: read.rejected,
        truncated: read.stopped.is_some(),
        truncation: read.stopped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writer_debug_and_path() {
        let dir = std::env::temp_dir().join(format!("terl-telemetry-unit-{}", std::process::id()));
        let path = crate::dataset_path(&dir);
        assert!(path.ends_with("tep-dataset.mcap"));
        let _ = std::fs::remove_file(&path);
        let writer = TepDatasetWriter::create(&path).unwrap();
        assert!(format!("{writer:?}").contains("finished: false"));
        assert_eq!(writer.finish().unwrap(), 0);
        let dataset = read_tep_dataset(&path).unwrap();
        assert_eq!(dataset, TepDataset::default());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
