//! One protobuf channel in an MCAP file: the writer and the crash-tolerant reader every log of a
//! run shares (TEP dataset, metrics, episodes). Layout and recovery are in the crate docs.

use std::{
    collections::{BTreeMap, HashMap, HashSet},
    fs::{self, File, OpenOptions},
    io::{self, BufReader, BufWriter},
    path::{Path, PathBuf},
};

use mcap::{
    records::{MessageHeader, Record},
    sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions},
    McapError, WriteOptions, Writer,
};
use tracing::{debug, warn};

use crate::{Result, TelemetryError};

/// Schema and message encoding of every channel we write.
pub(crate) const PROTOBUF: &str = "protobuf";
/// Target uncompressed chunk size: a chunk is closed once it exceeds this (or on `flush`).
const CHUNK_SIZE: u64 = 1 << 20;
/// Buffer between the MCAP writer and the file.
const IO_BUFFER: usize = 256 << 10;

/// Which channel a log file carries.
#[doc(hidden)]
#[derive(Debug, Clone, Copy)]
pub struct Channel {
    pub topic: &'static str,
    /// Full protobuf message name, e.g. `terl.v1.TepSample`.
    pub schema: &'static str,
    /// What the file is, for log lines ("TEP dataset").
    pub what: &'static str,
}

/// Appends protobuf messages of one schema to one channel of a new MCAP file.
pub(crate) struct ProtoWriter {
    path: PathBuf,
    channel: Channel,
    /// `None` once finished.
    writer: Option<Writer<BufWriter<File>>>,
    channel_id: u16,
    messages: u64,
    buf: Vec<u8>,
}

impl ProtoWriter {
    /// Creates the file (and its parent directories): `replace` discards an existing file,
    /// otherwise an existing file is [`TelemetryError::AlreadyExists`].
    pub(crate) fn open(path: &Path, channel: Channel, replace: bool) -> Result<Self> {
        let mut options = OpenOptions::new();
        if replace {
            options.write(true).create(true).truncate(true);
        } else {
            options.write(true).create_new(true);
        }
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
            .add_schema(channel.schema, PROTOBUF, terl_wire::FILE_DESCRIPTOR_SET)
            .map_err(mcap_err)?;
        let channel_id = writer
            .add_channel(schema_id, channel.topic, PROTOBUF, &BTreeMap::new())
            .map_err(mcap_err)?;
        // Schema and channel go to disk at once, so even an empty, killed file is recognisable.
        writer.flush().map_err(mcap_err)?;
        debug!(path = %path.display(), "{} created", channel.what);
        Ok(Self {
            path: path.to_owned(),
            channel,
            writer: Some(writer),
            channel_id,
            messages: 0,
            buf: Vec::with_capacity(1024),
        })
    }

    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    pub(crate) fn messages(&self) -> u64 {
        self.messages
    }

    pub(crate) fn is_finished(&self) -> bool {
        self.writer.is_none()
    }

    fn mcap_err(&self, source: McapError) -> TelemetryError {
        TelemetryError::Mcap {
            path: self.path.clone(),
            source,
        }
    }

    /// Appends one message; `log_time_ns` becomes its log and publish time.
    pub(crate) fn write(&mut self, message: &impl prost::Message, log_time_ns: u64) -> Result<()> {
        self.buf.clear();
        message
            .encode(&mut self.buf)
            .expect("a Vec grows to fit any message");
        let header = MessageHeader {
            channel_id: self.channel_id,
            // MCAP sequence numbers are 32-bit; they may wrap in a huge file, which readers
            // tolerate (the log time orders messages).
            sequence: self.messages as u32,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        let Some(writer) = self.writer.as_mut() else {
            // Only reachable after a failed `finish`, which consumed the writer anyway.
            return Err(self.mcap_err(McapError::AttemptedWriteAfterFailure));
        };
        let result = writer.write_to_known_channel(&header, &self.buf);
        result.map_err(|e| self.mcap_err(e))?;
        self.messages += 1;
        Ok(())
    }

    /// Closes the current chunk and hands everything written so far to the operating system.
    pub(crate) fn flush(&mut self) -> Result<()> {
        let Some(writer) = self.writer.as_mut() else {
            return Err(self.mcap_err(McapError::AttemptedWriteAfterFailure));
        };
        let result = writer.flush();
        result.map_err(|e| self.mcap_err(e))
    }

    /// Writes the summary and footer and syncs the file; returns the message count.
    pub(crate) fn finish(&mut self) -> Result<u64> {
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
        debug!(path = %self.path.display(), messages = self.messages, "{} finished", self.channel.what);
        Ok(self.messages)
    }
}

impl Drop for ProtoWriter {
    fn drop(&mut self) {
        if self.writer.is_some() {
            if let Err(err) = self.finish() {
                warn!(%err, "{} writer dropped: finishing the file failed", self.channel.what);
            }
        }
    }
}

/// Every message of a channel, decoded and checked by the caller's `accept`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Messages<T> {
    pub(crate) items: Vec<T>,
    pub(crate) rejected: u64,
    pub(crate) truncated: bool,
}

/// Reads every message on `channel` of the MCAP file at `path`, front to back with the mcap
/// crate's linear reader, using only chunks whose CRC matches. `accept` decodes and validates
/// one message's bytes; refusals are counted and skipped with one warning. A file that ends
/// early or breaks off yields what came before, with `truncated` set.
pub(crate) fn read_channel<T>(
    path: &Path,
    channel: Channel,
    mut accept: impl FnMut(&[u8]) -> std::result::Result<T, String>,
) -> Result<Messages<T>> {
    let io_err = |source| TelemetryError::Io {
        path: path.to_owned(),
        source,
    };
    let mut input = BufReader::with_capacity(IO_BUFFER, File::open(path).map_err(io_err)?);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default().with_prevalidate_chunk_crcs(true),
    );
    let mut state = ReadState {
        channel,
        header_seen: false,
        schemas: HashMap::new(),
        channels: HashSet::new(),
        stats_count: None,
        first_rejection: None,
        out: Messages {
            items: Vec::new(),
            rejected: 0,
            truncated: false,
        },
    };
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
            Ok(record) => state.record(path, record, &mut accept)?,
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
            messages = state.out.items.len(),
            "{} is truncated or damaged ({err}); keeping the messages before that point",
            channel.what
        );
        state.out.truncated = true;
    }
    if state.channels.is_empty() {
        return Err(TelemetryError::NoChannel {
            path: path.to_owned(),
            topic: channel.topic,
            what: channel.what,
            truncated: state.out.truncated,
        });
    }
    if let Some(reason) = &state.first_rejection {
        warn!(
            path = %path.display(),
            rejected = state.out.rejected,
            "skipped invalid messages in the {}; the first: {reason}",
            channel.what
        );
    }
    if let Some(expected) = state.stats_count {
        let got = state.out.items.len() as u64 + state.out.rejected;
        if got != expected {
            warn!(
                path = %path.display(),
                "the file's statistics count {expected} {} messages, but {got} were read",
                channel.topic
            );
        }
    }
    Ok(state.out)
}

/// `read` that retries on `Interrupted`.
fn read_some(input: &mut impl io::Read, buf: &mut [u8]) -> io::Result<usize> {
    loop {
        match input.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            other => return other,
        }
    }
}

struct ReadState<T> {
    channel: Channel,
    header_seen: bool,
    /// Schema id → (name, encoding).
    schemas: HashMap<u16, (String, String)>,
    /// Ids of the validated channels on the wanted topic.
    channels: HashSet<u16>,
    /// Message count of those channels from the Statistics record, if any.
    stats_count: Option<u64>,
    first_rejection: Option<String>,
    out: Messages<T>,
}

impl<T> ReadState<T> {
    fn record(
        &mut self,
        path: &Path,
        record: Record<'_>,
        accept: &mut impl FnMut(&[u8]) -> std::result::Result<T, String>,
    ) -> Result<()> {
        let want = self.channel;
        match record {
            Record::Header(_) => self.header_seen = true,
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(channel) if channel.topic == want.topic => {
                let problem = match self.schemas.get(&channel.schema_id) {
                    _ if channel.message_encoding != PROTOBUF => Some(format!(
                        "has message encoding {:?}, expected {PROTOBUF:?}",
                        channel.message_encoding
                    )),
                    None => Some(format!(
                        "refers to schema {}, which the file does not define before it",
                        channel.schema_id
                    )),
                    Some((name, encoding)) if name != want.schema || encoding != PROTOBUF => {
                        Some(format!(
                            "has schema {name:?} ({encoding:?}), expected {:?} ({PROTOBUF:?})",
                            want.schema
                        ))
                    }
                    Some(_) => None,
                };
                if let Some(problem) = problem {
                    return Err(TelemetryError::WrongSchema {
                        path: path.to_owned(),
                        topic: want.topic,
                        problem,
                    });
                }
                self.channels.insert(channel.id);
            }
            Record::Message { header, data } if self.channels.contains(&header.channel_id) => {
                match accept(data.as_ref()) {
                    Ok(item) => self.out.items.push(item),
                    Err(reason) => {
                        self.out.rejected += 1;
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
                    self.channels
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
