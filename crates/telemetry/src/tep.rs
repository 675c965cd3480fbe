//! [`TepDatasetWriter`] and [`read_tep_dataset`]: the TEP dataset as MCAP (layout and crash
//! recovery in the crate docs).

use std::{
    collections::{BTreeMap, HashMap, HashSet},
    fmt,
    fs::{self, File, OpenOptions},
    io::{self, BufReader, BufWriter, Read},
    path::{Path, PathBuf},
};

use mcap::{
    records::{MessageHeader, Record},
    sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions},
    McapError, WriteOptions, Writer,
};
use prost::Message as _;
use terl_wire::{pb, TepSample};
use tracing::{debug, warn};

use crate::{Result, TelemetryError};

/// Topic of the TEP samples.
pub const TEP_TOPIC: &str = "/tep/samples";
/// Schema name (the protobuf message's full name) of the TEP samples.
pub const TEP_SCHEMA_NAME: &str = "terl.v1.TepSample";
/// Schema and message encoding of every channel we write.
const PROTOBUF: &str = "protobuf";
/// Target uncompressed chunk size: a chunk is closed once it exceeds this (or on `flush`).
const CHUNK_SIZE: u64 = 1 << 20;
/// Buffer between the MCAP writer and the file.
const IO_BUFFER: usize = 256 << 10;

/// Appends `terl.v1.TepSample` messages to an MCAP file (one schema, one channel, topic
/// [`TEP_TOPIC`]).
///
/// [`create`](Self::create) never overwrites an existing file and [`replace`](Self::replace)
/// starts the file over; appending to an existing dataset is not supported (a resumed run starts a
/// new file). Call [`flush`](Self::flush) at points you want to survive a crash and
/// [`finish`](Self::finish) at the end; dropping an unfinished writer finishes it too, logging
/// errors instead of returning them.
pub struct TepDatasetWriter {
    path: PathBuf,
    /// `None` once finished.
    writer: Option<Writer<BufWriter<File>>>,
    channel_id: u16,
    messages: u64,
    /// Reused encode buffer.
    buf: Vec<u8>,
}

impl fmt::Debug for TepDatasetWriter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TepDatasetWriter")
            .field("path", &self.path)
            .field("finished", &self.writer.is_none())
            .field("messages", &self.messages)
            .finish_non_exhaustive()
    }
}

impl TepDatasetWriter {
    /// Creates a new dataset at `path` (and its parent directories). Fails with
    /// [`TelemetryError::AlreadyExists`] if the file exists.
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        Self::open_with(
            path.as_ref(),
            OpenOptions::new().write(true).create_new(true),
        )
    }

    /// Creates the dataset at `path` (and its parent directories), discarding any file there.
    pub fn replace(path: impl AsRef<Path>) -> Result<Self> {
        Self::open_with(
            path.as_ref(),
            OpenOptions::new().write(true).create(true).truncate(true),
        )
    }

    fn open_with(path: &Path, options: &OpenOptions) -> Result<Self> {
        let io_err = |source| TelemetryError::Io {
            path: path.to_owned(),
            source,
        };
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            fs::create_dir_all(parent).map_err(io_err)?;
        }
        let file = options.open(path).map_err(|source| {
            if source.kind() == io::ErrorKind::AlreadyExists {
                TelemetryError::AlreadyExists {
                    path: path.to_owned(),
                }
            } else {
                io_err(source)
            }
        })?;
        let mcap_err = |source| TelemetryError::Mcap {
            path: path.to_owned(),
            source,
        };
        let mut writer = WriteOptions::new()
            .compression(None)
            .library(concat!("terl-telemetry ", env!("CARGO_PKG_VERSION")))
            .chunk_size(Some(CHUNK_SIZE))
            // Chunks are built in memory and written whole: a killed writer never leaves a chunk
            // header with placeholder lengths in the file.
            .disable_seeking(true)
            .create(BufWriter::with_capacity(IO_BUFFER, file))
            .map_err(mcap_err)?;
        let schema_id = writer
            .add_schema(TEP_SCHEMA_NAME, PROTOBUF, terl_wire::FILE_DESCRIPTOR_SET)
            .map_err(mcap_err)?;
        let channel_id = writer
            .add_channel(schema_id, TEP_TOPIC, PROTOBUF, &BTreeMap::new())
            .map_err(mcap_err)?;
        // Schema and channel go to disk at once, so even an empty, killed dataset is recognisable.
        writer.flush().map_err(mcap_err)?;
        debug!(path = %path.display(), "TEP dataset created");
        Ok(Self {
            path: path.to_owned(),
            writer: Some(writer),
            channel_id,
            messages: 0,
            buf: Vec::with_capacity(1024),
        })
    }

    /// Path of the file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Messages written so far.
    pub fn messages(&self) -> u64 {
        self.messages
    }

    fn mcap_err(&self, source: McapError) -> TelemetryError {
        TelemetryError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    fn writer(&mut self) -> Result<&mut Writer<BufWriter<File>>> {
        match self.writer.as_mut() {
            Some(w) => Ok(w),
            // Only reachable after a failed `finish`, which consumed the writer anyway.
            None => Err(TelemetryError::Mcap {
                path: self.path.clone(),
                source: McapError::AttemptedWriteAfterFailure,
            }),
        }
    }

    /// Appends one sample; `log_time_ns` becomes the message's log and publish time (nanoseconds,
    /// by convention since the Unix epoch).
    pub fn write(&mut self, sample: &TepSample, log_time_ns: u64) -> Result<()> {
        self.buf.clear();
        pb::TepSample::from(sample)
            .encode(&mut self.buf)
            .expect("a Vec grows to fit any message");
        let header = MessageHeader {
            channel_id: self.channel_id,
            // MCAP sequence numbers are 32-bit; they may wrap in a huge dataset, which readers
            // tolerate (the log time orders messages).
            sequence: self.messages as u32,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        let mut buf = std::mem::take(&mut self.buf);
        let result = self.writer()?.write_to_known_channel(&header, &buf);
        buf.clear();
        self.buf = buf;
        result.map_err(|e| self.mcap_err(e))?;
        self.messages += 1;
        Ok(())
    }

    /// Closes the current chunk and hands everything written so far to the operating system:
    /// from now on a crash or kill of this process cannot lose those samples.
    pub fn flush(&mut self) -> Result<()> {
        let result = self.writer()?.flush();
        result.map_err(|e| self.mcap_err(e))
    }

    /// Writes the summary and footer, syncs the file to disk and returns the number of messages.
    pub fn finish(mut self) -> Result<u64> {
        self.finish_inner()
    }

    fn finish_inner(&mut self) -> Result<u64> {
        let Some(mut writer) = self.writer.take() else {
            return Ok(self.messages);
        };
        writer.finish().map_err(|e| self.mcap_err(e))?;
        let file = writer
            .into_inner()
            .into_inner()
            .map_err(|e| e.into_error())
            .and_then(|file| file.sync_all());
        file.map_err(|source| TelemetryError::Io {
            path: self.path.clone(),
            source,
        })?;
        debug!(path = %self.path.display(), messages = self.messages, "TEP dataset finished");
        Ok(self.messages)
    }
}

impl Drop for TepDatasetWriter {
    fn drop(&mut self) {
        if self.writer.is_some() {
            if let Err(err) = self.finish_inner() {
                warn!(%err, "TEP dataset writer dropped: finishing the file failed");
            }
        }
    }
}

/// The samples of a TEP dataset file.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TepDataset {
    /// Valid samples, in file order.
    pub samples: Vec<TepSample>,
    /// Messages on [`TEP_TOPIC`] that did not decode or failed validation (skipped).
    pub rejected: u64,
    /// The file ended early or has a damaged tail (its writer was killed): `samples` holds what
    /// was complete before that point.
    pub truncated: bool,
}

/// Reads every sample on [`TEP_TOPIC`] of the MCAP file at `path`.
///
/// The file is read front to back (see the crate docs): messages are decoded with prost and
/// validated with `TryFrom<pb::TepSample>`; invalid ones are counted in
/// [`TepDataset::rejected`] and skipped with one warning. A file that ends early or breaks off
/// (a killed writer) yields its complete chunks with [`TepDataset::truncated`] set. Errors: the
/// file cannot be read, is not MCAP, has no [`TEP_TOPIC`] channel, or that channel's schema or
/// encoding is not `terl.v1.TepSample` / protobuf.
pub fn read_tep_dataset(path: impl AsRef<Path>) -> Result<TepDataset> {
    let path = path.as_ref();
    let io_err = |source| TelemetryError::Io {
        path: path.to_owned(),
        source,
    };
    let mut input = BufReader::with_capacity(IO_BUFFER, File::open(path).map_err(io_err)?);
    let mut reader = LinearReader::new_with_options(
        // Only chunks whose CRC matches are used: a partial or damaged chunk yields nothing.
        LinearReaderOptions::default().with_prevalidate_chunk_crcs(true),
    );
    let mut state = ReadState::default();
    let mut stopped: Option<McapError> = None;
    while let Some(event) = reader.next_event() {
        let record = match event {
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let read = read_some(&mut input, reader.insert(need)).map_err(io_err)?;
                reader.notify_read(read);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => mcap::parse_record(opcode, data),
            Err(err) => Err(err),
        };
        match record {
            Ok(record) => state.record(path, record)?,
            Err(err) => {
                stopped = Some(err);
                break;
            }
        }
    }
    if let Some(err) = stopped {
        if !state.header_seen {
            return Err(TelemetryError::NotMcap {
                path: path.to_owned(),
                source: err,
            });
        }
        warn!(
            path = %path.display(),
            samples = state.dataset.samples.len(),
            "TEP dataset is truncated or damaged ({err}); keeping the samples before that point"
        );
        state.dataset.truncated = true;
    }
    if state.tep_channels.is_empty() {
        return Err(TelemetryError::NoTepChannel {
            path: path.to_owned(),
            truncated: state.dataset.truncated,
        });
    }
    if let Some(reason) = &state.first_rejection {
        warn!(
            path = %path.display(),
            rejected = state.dataset.rejected,
            "skipped invalid TEP samples; the first: {reason}"
        );
    }
    if let Some(expected) = state.stats_count {
        let got = state.dataset.samples.len() as u64 + state.dataset.rejected;
        if got != expected {
            warn!(
                path = %path.display(),
                "the file's statistics count {expected} {TEP_TOPIC} messages, but {got} were read"
            );
        }
    }
    Ok(state.dataset)
}

/// `read` that retries on `Interrupted`.
fn read_some(input: &mut impl Read, buf: &mut [u8]) -> io::Result<usize> {
    loop {
        match input.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            other => return other,
        }
    }
}

#[derive(Default)]
struct ReadState {
    header_seen: bool,
    /// Schema id → (name, encoding).
    schemas: HashMap<u16, (String, String)>,
    /// Ids of the validated channels on `TEP_TOPIC`.
    tep_channels: HashSet<u16>,
    /// Message count of the `TEP_TOPIC` channels from the Statistics record, if any.
    stats_count: Option<u64>,
    first_rejection: Option<String>,
    dataset: TepDataset,
}

impl ReadState {
    fn record(&mut self, path: &Path, record: Record<'_>) -> Result<()> {
        match record {
            Record::Header(_) => self.header_seen = true,
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(channel) if channel.topic == TEP_TOPIC => {
                let problem = match self.schemas.get(&channel.schema_id) {
                    _ if channel.message_encoding != PROTOBUF => Some(format!(
                        "has message encoding {:?}, expected {PROTOBUF:?}",
                        channel.message_encoding
                    )),
                    None => Some(format!(
                        "refers to schema {}, which the file does not define before it",
                        channel.schema_id
                    )),
                    Some((name, encoding)) if name != TEP_SCHEMA_NAME || encoding != PROTOBUF => {
                        Some(format!(
                            "has schema {name:?} ({encoding:?}), expected \
                             {TEP_SCHEMA_NAME:?} ({PROTOBUF:?})"
                        ))
                    }
                    Some(_) => None,
                };
                if let Some(problem) = problem {
                    return Err(TelemetryError::WrongSchema {
                        path: path.to_owned(),
                        problem,
                    });
                }
                self.tep_channels.insert(channel.id);
            }
            Record::Message { header, data } if self.tep_channels.contains(&header.channel_id) => {
                let sample = pb::TepSample::decode(data.as_ref())
                    .map_err(|e| format!("protobuf decode failed: {e}"))
                    .and_then(|m| TepSample::try_from(m).map_err(|s| s.message().to_owned()));
                match sample {
                    Ok(sample) => self.dataset.samples.push(sample),
                    Err(reason) => {
                        self.dataset.rejected += 1;
                        self.first_rejection.get_or_insert_with(|| {
                            format!(
                                "message {} (log time {}): {reason}",
                                header.sequence, header.log_time
                            )
                        });
                    }
                }
            }
            Record::Statistics(stats) => {
                self.stats_count = Some(
                    self.tep_channels
                        .iter()
                        .filter_map(|id| stats.channel_message_counts.get(id))
                        .sum(),
                );
            }
            _ => {}
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writer_debug_and_path() {
        let dir = std::env::temp_dir().join(format!("terl-telemetry-unit-{}", std::process::id()));
        let path = crate::dataset_path(&dir);
        assert!(path.ends_with("tep-dataset.mcap"));
        let _ = fs::remove_file(&path);
        let writer = TepDatasetWriter::create(&path).unwrap();
        assert!(format!("{writer:?}").contains("finished: false"));
        assert_eq!(writer.finish().unwrap(), 0);
        let dataset = read_tep_dataset(&path).unwrap();
        assert_eq!(dataset, TepDataset::default());
        fs::remove_dir_all(&dir).unwrap();
    }
}
