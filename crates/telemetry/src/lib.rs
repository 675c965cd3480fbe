//! The MCAP logs of a run: the TEP dataset (`<run_dir>/tep-dataset.mcap`, written by the
//! selector), learner metrics (`metrics.mcap`) and finished episodes (`episodes.mcap`, selector),
//! each one protobuf channel with the same layout and crash recovery as described here for the
//! dataset.
//!
//! # The TEP dataset file
//!
//! One [MCAP](https://mcap.dev/spec) file per run, written by [`TepDatasetWriter`] and read back by
//! [`read_tep_dataset`]. Every message is one `terl.v1.TepSample` (`proto/terl/v1/dataset.proto`)
//! encoded with prost, so any MCAP tool with protobuf support (Foxglove, the `mcap` CLI, the
//! Python `mcap` + `mcap-protobuf-support` readers) decodes the file without our code:
//!
//! ```text
//! magic, Header (library "terl-telemetry <version>")
//! chunk 1:   Schema  name "terl.v1.TepSample", encoding "protobuf",
//!                    data = terl_wire::FILE_DESCRIPTOR_SET (encoded google.protobuf.FileDescriptorSet)
//!            Channel topic "/tep/samples", message encoding "protobuf"
//! chunk 2..: Message records (log time = the caller's timestamp), uncompressed, each chunk
//!            closed at ~1 MiB or by TepDatasetWriter::flush, followed by its MessageIndex records
//! DataEnd, summary (Schema, Channel, Statistics, ChunkIndex), SummaryOffsets, Footer, magic
//! ```
//!
//! # Crash recovery
//!
//! Chunks are assembled in memory and reach the file only once complete (the writer runs with
//! seeking disabled), and [`TepDatasetWriter::flush`] closes the current chunk and hands it to the
//! operating system. A writer killed at any point therefore leaves a file that is a valid MCAP
//! prefix: complete chunks, possibly followed by a partial chunk, and no summary or footer.
//! [`read_tep_dataset`] reads the file front to back with the mcap crate's linear reader, checking
//! every chunk's CRC before using it; where the file ends early or stops making sense it keeps
//! everything before that point and reports [`TepDataset::truncated`] instead of failing. Data the
//! process had flushed survives a kill; surviving a power loss additionally needs the file synced,
//! which [`TepDatasetWriter::finish`] does.

mod log;
mod records;
mod tep;

use std::path::{Path, PathBuf};

pub use records::{
    episodes_path, metrics_path, read_log, EpisodeLogWriter, LogRecord, LogWriter, Logged,
    MetricsWriter,
};
pub use tep::{read_tep_dataset, TepDataset, TepDatasetWriter, TEP_SCHEMA_NAME, TEP_TOPIC};

/// File name of the TEP dataset inside a run directory.
pub const TEP_DATASET_FILE: &str = "tep-dataset.mcap";

/// Where a run keeps its TEP dataset: `run_dir/tep-dataset.mcap`.
pub fn dataset_path(run_dir: &Path) -> PathBuf {
    run_dir.join(TEP_DATASET_FILE)
}

/// `run_dir/<stem>.mcap`, or `run_dir/<stem>.<k>.mcap` (k = 2, 3, …) for the first that does not
/// exist yet: a service restarted into the same run folder starts a new file next to the
/// earlier ones instead of failing or overwriting them.
pub fn fresh_path(run_dir: &Path, stem: &str) -> PathBuf {
    let first = run_dir.join(format!("{stem}.mcap"));
    if !first.exists() {
        return first;
    }
    (2u64..)
        .map(|k| run_dir.join(format!("{stem}.{k}.mcap")))
        .find(|p| !p.exists())
        .expect("some index is free")
}

/// What can go wrong writing or reading a telemetry file.
#[derive(Debug, thiserror::Error)]
pub enum TelemetryError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{path} already exists; log writers never overwrite a file \
         (TepDatasetWriter::replace starts a dataset over)"
    )]
    AlreadyExists { path: PathBuf },
    #[error("{path}: MCAP error: {source}")]
    Mcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path} is not an MCAP file ({source})")]
    NotMcap {
        path: PathBuf,
        #[source]
        source: mcap::McapError,
    },
    #[error("{path} has no channel on topic {topic} (not a {what}){}",
        if *truncated { "; the file is also truncated" } else { "" })]
    NoChannel {
        path: PathBuf,
        topic: &'static str,
        what: &'static str,
        truncated: bool,
    },
    #[error("{path}: channel {topic} {problem}")]
    WrongSchema {
        path: PathBuf,
        topic: &'static str,
        problem: String,
    },
}

/// Result of this crate's operations.
pub type Result<T, E = TelemetryError> = std::result::Result<T, E>;
