//! One protobuf channel in an MCAP file: the writer and the crash-tolerant reader every log of a
//! run shares (TEP dataset, metrics, episodes). Layout and recovery are in the crate docs.

use std::{
    collections::{BTreeMap, HashMap, HashSet},
    fs::{self, File, OpenOptions},
    io::{self, BufReader, BufWriter, Read as _},
    path::{Path, PathBuf},
};

use mcap::{
    records::{op, MessageHeader, Record},
    sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions},
    McapError, WriteOptions, Writer,
};
use tracing::{debug, warn};

use crate::{Result, TelemetryError};

/// Schema and message encoding of every channel we write.
pub(crate) const PROTOBUF: &str = "protobuf";
/// Target uncompressed chunk size: a chunk is closed once it exceeds this (or on `flush`).
const CHUNK_SIZE: u64 = 1 << 20;
/// Buffer between the MCAP writer and the file (and between the file and the reader).
const IO_BUFFER: usize = 256 << 10;
/// Most bytes the reader's buffer grows by per read: however long a record claims to be, the
/// buffer only ever holds bytes that were really read from the file.
const READ_STEP: usize = 1 << 20;

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
    /// The first write, flush or finish that failed, with its causes: later calls report it.
    failed: Option<String>,
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
            failed: None,
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

    /// The error of a failed call: the first failure is reported as it is and remembered;
    /// every later one names that first failure (the `mcap` writer only says "attempted
    /// another write after a write method failed").
    fn mcap_err(&mut self, source: McapError) -> TelemetryError {
        self.failure(TelemetryError::Mcap {
            path: self.path.clone(),
            source,
        })
    }

    fn failure(&mut self, err: TelemetryError) -> TelemetryError {
        if let Some(first) = &self.failed {
            return TelemetryError::AfterFailedWrite {
                path: self.path.clone(),
                first: first.clone(),
            };
        }
        let mut text = err.to_string();
        let mut cause = std::error::Error::source(&err);
        while let Some(c) = cause {
            let c_text = c.to_string();
            if !text.contains(&c_text) {
                text = format!("{text}: {c_text}");
            }
            cause = c.source();
        }
        self.failed = Some(text);
        err
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
        if let Err(e) = result {
            return Err(self.mcap_err(e));
        }
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
        if let Err(e) = writer.finish() {
            return Err(self.mcap_err(e));
        }
        let file = writer
            .into_inner()
            .into_inner()
            .map_err(|e| e.into_error())
            .and_then(|file| file.sync_all());
        if let Err(source) = file {
            let err = TelemetryError::Io {
                path: self.path.clone(),
                source,
            };
            return Err(self.failure(err));
        }
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
    /// Why reading stopped before the end of a complete file, if it did.
    pub(crate) stopped: Option<String>,
}

/// Library name our writer puts in the header (followed by its version).
const OUR_LIBRARY: &str = "terl-telemetry ";

/// Reads every message on `channel` of the MCAP file at `path`, front to back. `accept` decodes
/// and validates one message's bytes; refusals are counted and skipped with one warning. A file
/// that ends early or breaks off (a cut, a damaged length, a chunk whose CRC does not match)
/// yields what came before, with the reason in `stopped`.
///
/// Reading is bounded by the file as it is when reading begins: the mcap crate's linear reader
/// refuses any record that claims more bytes than that, the buffer grows only by bytes really
/// read, and bytes appended by a writer still running are left for the next read. Chunks are
/// taken whole, their CRC checked before any record in them is used, and their records split
/// here with every length checked against the chunk. In a file of our writer, which puts every
/// message in a chunk, numbers them 0, 1, 2, … and writes only the MCAP specification's
/// records, a message outside a chunk, a jump in the numbering or an unknown opcode (a chunk
/// lost to a damaged opcode) also ends the read; and a complete file whose statistics count
/// more messages than were found is reported as read in part.
pub(crate) fn read_channel<T>(
    path: &Path,
    channel: Channel,
    mut accept: impl FnMut(&[u8]) -> std::result::Result<T, String>,
) -> Result<Messages<T>> {
    let io_err = |source| TelemetryError::Io {
        path: path.to_owned(),
        source,
    };
    // Only a regular file is opened: opening a pipe blocks until a writer comes, and a device
    // has no size to bound the reading by.
    if !std::fs::metadata(path).map_err(io_err)?.is_file() {
        return Err(io_err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (a folder, pipe, socket or device)",
        )));
    }
    let file = File::open(path).map_err(io_err)?;
    let size = file.metadata().map_err(io_err)?.len();
    let mut input = BufReader::with_capacity(IO_BUFFER, file.take(size));
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_record_length_limit(usize::try_from(size).unwrap_or(usize::MAX)),
    );
    let mut state = ReadState {
        channel,
        header_seen: false,
        ours: false,
        schemas: HashMap::new(),
        channels: HashSet::new(),
        stats_count: None,
        first_rejection: None,
        out: Messages {
            items: Vec::new(),
            rejected: 0,
            stopped: None,
        },
    };
    let mut stopped: Option<Stop> = None;
    while let Some(event) = reader.next_event() {
        let step = match event {
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let buf = reader.insert(need.min(READ_STEP));
                let read = read_some(&mut input, buf).map_err(io_err)?;
                reader.notify_read(read);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) if opcode == op::CHUNK => {
                state.chunk(data, &mut accept)
            }
            Ok(LinearReadEvent::Record { opcode, data }) => {
                state.record(opcode, data, false, &mut accept)
            }
            Err(err) => Err(Stop::Mcap(err)),
        };
        match step {
            Ok(()) => {}
            Err(Stop::WrongSchema(problem)) if state.channels.is_empty() => {
                return Err(TelemetryError::WrongSchema {
                    path: path.to_owned(),
                    topic: channel.topic,
                    problem,
                });
            }
            Err(stop) => {
                stopped = Some(stop);
                break;
            }
        }
    }
    if let Some(stop) = stopped {
        if !state.header_seen {
            let reason = match stop {
                Stop::Mcap(err) => err.to_string(),
                other => other.reason(size),
            };
            return Err(TelemetryError::NotMcap {
                path: path.to_owned(),
                reason,
            });
        }
        let reason = stop.reason(size);
        // The caller gets the reason in `stopped` and tells its user in its own words (every
        // caller does); a warning here as well doubled each of those messages.
        debug!(
            path = %path.display(),
            messages = state.out.items.len(),
            "{} is read only in part: {reason}; keeping the messages before that point",
            channel.what
        );
        state.out.stopped = Some(reason);
    }
    if state.channels.is_empty() {
        return Err(TelemetryError::NoChannel {
            path: path.to_owned(),
            topic: channel.topic,
            what: channel.what,
            truncated: state.out.stopped.is_some(),
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
        if got < expected && state.out.stopped.is_none() {
            // A complete file that lacks messages: a chunk was lost to damage the reader could
            // not see (say, a damaged opcode on the last one).
            let reason = format!(
                "the file's statistics count {expected} messages on {}, but only {got} were \
                 found: the others were lost to a damaged record",
                channel.topic
            );
            debug!(path = %path.display(), "{} is read only in part: {reason}", channel.what);
            state.out.stopped = Some(reason);
        } else if got != expected {
            warn!(
                path = %path.display(),
                "the file's statistics count {expected} {} messages, but {got} were read",
                channel.topic
            );
        }
    }
    Ok(state.out)
}

/// What stopped a read before the end of the file.
#[derive(Debug)]
enum Stop {
    Mcap(McapError),
    /// A header, schema or channel record with a string longer than the record.
    LongString {
        opcode: u8,
    },
    /// The channel on our topic has the wrong schema or encoding: a foreign file if it comes
    /// before any valid channel, damage after one.
    WrongSchema(String),
    /// Any other damage, in words.
    Damaged(String),
}

impl Stop {
    /// Why reading stopped, in words, for a file of `size` bytes.
    fn reason(&self, size: u64) -> String {
        match self {
            Stop::Mcap(McapError::UnexpectedEof) => {
                "the file ends inside a record (its writer was stopped, or the file was cut)".into()
            }
            Stop::Mcap(McapError::RecordTooLarge { opcode, len }) => format!(
                "a record (opcode {opcode:#04x}) claims {len} bytes, more than the whole file \
                 ({size} bytes): a damaged length, or a file cut inside that record"
            ),
            Stop::Mcap(McapError::BadChunkCrc { saved, calculated }) => format!(
                "a chunk's records do not match its CRC (stored {saved:#010x}, computed \
                 {calculated:#010x}): the chunk is damaged"
            ),
            Stop::Mcap(other) => format!("damaged data ({other})"),
            Stop::LongString { opcode } => format!(
                "damaged data (a record with opcode {opcode:#04x} has a string longer than \
                 the record)"
            ),
            Stop::WrongSchema(problem) => {
                format!("damaged data (a later channel record on our topic {problem})")
            }
            Stop::Damaged(reason) => format!("damaged data ({reason})"),
        }
    }
}

/// Parses the records the reader uses (header, schema, channel, message, statistics); others
/// are skipped unparsed. mcap's parser reserves a string's stated length before reading it, so
/// the strings of header, schema and channel records are first checked to fit in the record.
fn parse_record(opcode: u8, data: &[u8]) -> std::result::Result<Option<Record<'_>>, Stop> {
    let fits = match opcode {
        op::HEADER => strings_end(data, 0, 2).is_some(),
        op::SCHEMA => strings_end(data, 2, 2).is_some(),
        op::CHANNEL => channel_strings_fit(data),
        op::MESSAGE | op::STATISTICS => true,
        _ => return Ok(None),
    };
    if !fits {
        return Err(Stop::LongString { opcode });
    }
    mcap::parse_record(opcode, data)
        .map(Some)
        .map_err(Stop::Mcap)
}

/// The records field of a chunk record's body, once its compression and CRC are checked.
fn chunk_records(data: &[u8]) -> std::result::Result<&[u8], Stop> {
    // message_start_time, message_end_time, uncompressed_size (u64 each), uncompressed_crc (u32),
    // compression (string), compressed_size (u64), records.
    const CRC_AT: usize = 24;
    const COMPRESSION_AT: usize = 28;
    let compression_end =
        strings_end(data, COMPRESSION_AT, 1).ok_or(Stop::LongString { opcode: op::CHUNK })?;
    let compression = &data[COMPRESSION_AT + 4..compression_end];
    if !compression.is_empty() {
        return Err(Stop::Damaged(format!(
            "a chunk compressed with {:?}, which this reader does not read",
            String::from_utf8_lossy(compression)
        )));
    }
    let crc = u32::from_le_bytes(data[CRC_AT..CRC_AT + 4].try_into().expect("4 bytes"));
    let size_end = compression_end + 8;
    let Some(size) = data.get(compression_end..size_end) else {
        return Err(Stop::Damaged(
            "a chunk record too short for its header".into(),
        ));
    };
    let size = u64::from_le_bytes(size.try_into().expect("8 bytes"));
    let available = data.len() - size_end;
    let records = usize::try_from(size)
        .ok()
        .filter(|&n| n <= available)
        .map(|n| &data[size_end..size_end + n])
        .ok_or_else(|| {
            Stop::Damaged(format!(
                "a chunk claims {size} bytes of records but holds {available}"
            ))
        })?;
    let calculated = crc32fast::hash(records);
    if crc != 0 && crc != calculated {
        return Err(Stop::Mcap(McapError::BadChunkCrc {
            saved: crc,
            calculated,
        }));
    }
    Ok(records)
}

/// Offset just past `n` length-prefixed strings (u32 little-endian length, then the bytes)
/// starting at `at`, or `None` if one of them runs past the end of `data`.
fn strings_end(data: &[u8], mut at: usize, n: usize) -> Option<usize> {
    for _ in 0..n {
        let len = data.get(at..at.checked_add(4)?)?;
        let len = u32::from_le_bytes(len.try_into().ok()?) as usize;
        at = at.checked_add(4)?.checked_add(len)?;
        if at > data.len() {
            return None;
        }
    }
    Some(at)
}

/// Whether a channel record's topic, encoding and metadata strings all fit in it.
fn channel_strings_fit(data: &[u8]) -> bool {
    let Some(at) = strings_end(data, 4, 2) else {
        return false;
    };
    let Some(map_len) = data.get(at..at + 4) else {
        return false;
    };
    let map_len = u32::from_le_bytes(map_len.try_into().expect("4 bytes")) as usize;
    let start = at + 4;
    let Some(end) = start.checked_add(map_len).filter(|&e| e <= data.len()) else {
        return false;
    };
    let mut at = start;
    while at < end {
        match strings_end(&data[..end], at, 2) {
            Some(next) => at = next,
            None => return false,
        }
    }
    true
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
    /// The header names our writer as the file's library.
    ours: bool,
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
    /// Uses the records of one chunk record (its body `data`), all or none.
    fn chunk(
        &mut self,
        data: &[u8],
        accept: &mut impl FnMut(&[u8]) -> std::result::Result<T, String>,
    ) -> std::result::Result<(), Stop> {
        let mut rest = chunk_records(data)?;
        while !rest.is_empty() {
            let Some((head, body)) = rest.split_first_chunk::<9>() else {
                return Err(Stop::Damaged("a chunk ends inside a record header".into()));
            };
            let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
            let Some(len) = usize::try_from(len).ok().filter(|&n| n <= body.len()) else {
                return Err(Stop::Damaged(format!(
                    "a record in a chunk claims {len} bytes but the chunk has {} left",
                    body.len()
                )));
            };
            self.record(head[0], &body[..len], true, accept)?;
            rest = &body[len..];
        }
        Ok(())
    }

    /// Uses one record (opcode and body) found inside a chunk or not.
    fn record(
        &mut self,
        opcode: u8,
        data: &[u8],
        in_chunk: bool,
        accept: &mut impl FnMut(&[u8]) -> std::result::Result<T, String>,
    ) -> std::result::Result<(), Stop> {
        if self.ours && !(op::HEADER..=op::DATA_END).contains(&opcode) {
            // Our writer writes only the records of the MCAP specification.
            return Err(Stop::Damaged(format!(
                "a record with opcode {opcode:#04x}, which the writer never writes"
            )));
        }
        let Some(record) = parse_record(opcode, data)? else {
            return Ok(());
        };
        let want = self.channel;
        match record {
            Record::Header(header) => {
                self.header_seen = true;
                self.ours = header.library.starts_with(OUR_LIBRARY);
            }
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
                    return Err(Stop::WrongSchema(problem));
                }
                self.channels.insert(channel.id);
            }
            Record::Message { header, data } if self.channels.contains(&header.channel_id) => {
                if self.ours {
                    if !in_chunk {
                        return Err(Stop::Damaged(
                            "a message outside any chunk, where the writer puts every message \
                             in a chunk"
                                .into(),
                        ));
                    }
                    // Sequence numbers are the writer's 32-bit message count.
                    let expected = (self.out.items.len() as u64 + self.out.rejected) as u32;
                    if header.sequence != expected {
                        return Err(Stop::Damaged(format!(
                            "message number {} follows {} messages: the messages between were \
                             lost to a damaged record",
                            header.sequence, expected
                        )));
                    }
                }
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
