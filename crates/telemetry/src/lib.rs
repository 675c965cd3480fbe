//! The MCAP logs of a run: the TEP dataset (`<run_dir>/tep-dataset.mcap`, written by the
//! selector), learner metrics (`metrics.mcap`), finished episodes (`episodes.mcap`, selector)
//! and in-run evaluations (`eval.mcap`, the selector's evaluator),
//! each one protobuf channel with the same layout and crash recovery as described here for the
//! dataset; and the same scalars as TensorBoard event files ([`EventWriter`]: the learner's
//! beside `metrics.mcap`, the evaluator's in `<run_dir>/eval/`).
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
//! everything before that point and reports [`TepDataset::truncated`], with the reason in
//! [`TepDataset::truncation`], instead of failing. Data the process had flushed survives a kill;
//! surviving a power loss additionally needs the file synced, which [`TepDatasetWriter::finish`]
//! does.
//!
//! # Damaged files
//!
//! Every length in the file is bounded by what is there before anything is allocated: the
//! reader reads the file as it is when reading begins, refuses any record or chunk that claims
//! more bytes than that (a damaged length), grows its buffer only by bytes really read, and
//! checks the strings of header, schema and channel records against their record before
//! parsing them. A damaged length, a flipped byte in a chunk (its CRC no longer matches) or a
//! cut anywhere therefore ends the read at that point with the messages before it kept and
//! `truncated` set, never a crash; records the reader does not need (indexes, attachments,
//! metadata) are skipped unparsed. Damage that would otherwise drop a chunk silently (its opcode
//! turned into another record's) shows in files of our writer as a gap in the message numbers,
//! an opcode the writer never writes, or fewer messages than the file's statistics count, and
//! ends or marks the read the same way.

#![warn(missing_docs)]

mod log;
mod records;
mod tensorboard;
mod tep;

use std::path::{Path, PathBuf};

pub use records::{
    episodes_path, eval_path, metrics_path, read_log, read_run_log, CutSegment, EpisodeLogWriter,
    EvalLogWriter, LogRecord, LogWriter, Logged, MetricsWriter, RunLog,
};
pub use tensorboard::EventWriter;
pub use tep::{read_tep_dataset, TepDataset, TepDatasetWriter, TEP_SCHEMA_NAME, TEP_TOPIC};

/// File name of the TEP dataset inside a run directory.
pub const TEP_DATASET_FILE: &str = "tep-dataset.mcap";

/// Where a run keeps its TEP dataset: `run_dir/tep-dataset.mcap`.
pub fn dataset_path(run_dir: &Path) -> PathBuf {
    run_dir.join(TEP_DATASET_FILE)
}

/// The `k`-th file of a log: `run_dir/<stem>.mcap` for k = 1, `run_dir/<stem>.<k>.mcap` after.
fn numbered_path(run_dir: &Path, stem: &str, k: u64) -> PathBuf {
    if k == 1 {
        run_dir.join(format!("{stem}.mcap"))
    } else {
        run_dir.join(format!("{stem}.{k}.mcap"))
    }
}

/// Something is at `path` (a file, a folder, or a symbolic link even if dangling or looping):
/// unlike [`Path::exists`], a damaged link under a log's name is not mistaken for no log.
fn present(path: &Path) -> bool {
    std::fs::symlink_metadata(path).is_ok()
}

/// `run_dir/<stem>.mcap`, or `run_dir/<stem>.<k>.mcap` (k = 2, 3, …) for the first that does not
/// exist yet: a service restarted into the same run folder starts a new file next to the
/// earlier ones instead of failing or overwriting them.
pub fn fresh_path(run_dir: &Path, stem: &str) -> PathBuf {
    (1u64..)
        .map(|k| numbered_path(run_dir, stem, k))
        .find(|p| !present(p))
        .expect("some index is free")
}

/// The files of a log that [`fresh_path`] handed out, in order (empty if there is none). An
/// entry that cannot be read (a dangling or looping link) is listed, so that reading it fails
/// loudly instead of the log silently ending before it.
pub fn existing_paths(run_dir: &Path, stem: &str) -> Vec<PathBuf> {
    (1u64..)
        .map(|k| numbered_path(run_dir, stem, k))
        .take_while(|p| present(p))
        .collect()
}

/// The segments of a run's `<stem>` log that [`read_run_log`] does not read because an earlier
/// segment is missing (`<stem>.3.mcap` without `<stem>.2.mcap`, or any `<stem>.<k>.mcap`
/// without `<stem>.mcap`), sorted by k.
pub fn unread_segments(run_dir: &Path, stem: &str) -> Vec<PathBuf> {
    segments_after_gap(run_dir, stem, existing_paths(run_dir, stem).len() as u64)
}

/// The note a report gives for a segment [`unread_segments`] names.
pub fn unread_segment_note(path: &Path) -> String {
    format!(
        "note: {} is not read: an earlier segment of the same log is missing, so its place in \
         the run is unknown",
        path.display()
    )
}

/// The segments of a log numbered past a gap: `<stem>.<k>.mcap` with k > `read + 1` when
/// [`existing_paths`] found `read` segments (it stops at the first missing one), sorted by k.
/// Unreadable folders give none (the segments already found are read as usual).
pub(crate) fn segments_after_gap(run_dir: &Path, stem: &str, read: u64) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(run_dir) else {
        return Vec::new();
    };
    let prefix = format!("{stem}.");
    let mut found: Vec<(u64, PathBuf)> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name();
            let digits = name
                .to_str()?
                .strip_prefix(&prefix)?
                .strip_suffix(".mcap")?;
            // Only the names fresh_path hands out: plain decimal, no sign, no leading zero.
            if digits.is_empty()
                || digits.starts_with('0')
                || !digits.bytes().all(|b| b.is_ascii_digit())
            {
                return None;
            }
            let k = digits.parse::<u64>().ok()?;
            (k > read + 1).then(|| (k, e.path()))
        })
        .collect();
    found.sort();
    found.into_iter().map(|(_, p)| p).collect()
}

/// Now as nanoseconds since the Unix epoch: the log time of every record we write (0 if the
/// clock is before 1970).
pub fn unix_nanos() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// What can go wrong writing or reading a telemetry file.
#[derive(Debug, thiserror::Error)]
pub enum TelemetryError {
    /// Creating, opening, reading or syncing the file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A writer was asked to create a file that already exists.
    #[error(
        "{path} already exists; log writers never overwrite a file \
         (TepDatasetWriter::replace starts a dataset over)"
    )]
    AlreadyExists {
        /// The existing file.
        path: PathBuf,
    },
    /// The MCAP writer failed (or was used after a failure).
    #[error("{path}: MCAP error: {source}")]
    Mcap {
        /// The file being written.
        path: PathBuf,
        /// The error of the `mcap` crate.
        #[source]
        source: mcap::McapError,
    },
    /// A write after an earlier one on the same file failed: the MCAP writer takes nothing
    /// more, and `first` is why (the earlier error with its causes, e.g. "No space left on
    /// device"), which the `mcap` crate's own error for this case does not carry.
    #[error("{path}: not written, an earlier write of this file failed: {first}")]
    AfterFailedWrite {
        /// The file being written.
        path: PathBuf,
        /// The first failure on this file, in words with its causes.
        first: String,
    },
    /// Reading stopped before the file's MCAP header: not an MCAP file, or an empty or cut one.
    #[error("{path} is not an MCAP file ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// Why reading stopped, in words.
        reason: String,
    },
    /// The file is MCAP but holds no channel on the topic the reader expects.
    #[error("{path} has no channel on topic {topic} (not {} {what}){}",
        if what.starts_with(['a', 'e', 'i', 'o', 'u']) { "an" } else { "a" },
        if *truncated { "; the file is also truncated" } else { "" })]
    NoChannel {
        /// The file.
        path: PathBuf,
        /// The topic that was looked for.
        topic: &'static str,
        /// What kind of log that topic belongs to (e.g. "TEP dataset", "metrics log").
        what: &'static str,
        /// Reading also stopped early (the file is cut or damaged).
        truncated: bool,
    },
    /// The expected topic's channel has another message encoding or schema than protobuf
    /// with this log's message type (or a schema the file does not define before it).
    #[error("{path}: channel {topic} {problem}")]
    WrongSchema {
        /// The file.
        path: PathBuf,
        /// The channel's topic.
        topic: &'static str,
        /// What does not match, in words.
        problem: String,
    },
}

/// Result of this crate's operations.
pub type Result<T, E = TelemetryError> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresh_paths_number_restarts_and_existing_paths_lists_them_in_order() {
        let dir = std::env::temp_dir().join(format!("terl-paths-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        assert!(existing_paths(&dir, "episodes").is_empty());
        for want in ["episodes.mcap", "episodes.2.mcap", "episodes.3.mcap"] {
            let p = fresh_path(&dir, "episodes");
            assert_eq!(p, dir.join(want));
            std::fs::write(&p, b"").unwrap();
        }
        assert_eq!(
            existing_paths(&dir, "episodes"),
            ["episodes.mcap", "episodes.2.mcap", "episodes.3.mcap"].map(|n| dir.join(n))
        );
        assert!(existing_paths(&dir, "metrics").is_empty());
        // A link to itself under a log's name is listed (reading it then fails), not taken for
        // the end of the log, and never handed out as a fresh file.
        std::os::unix::fs::symlink("metrics.mcap", dir.join("metrics.mcap")).unwrap();
        assert_eq!(existing_paths(&dir, "metrics"), [dir.join("metrics.mcap")]);
        assert_eq!(fresh_path(&dir, "metrics"), dir.join("metrics.2.mcap"));
        let e = read_log::<terl_wire::Metric>(dir.join("metrics.mcap")).unwrap_err();
        assert!(e.to_string().contains("metrics.mcap"), "{e}");
        // A pipe is refused without being opened (opening would wait for a writer).
        let fifo = dir.join("eval.mcap");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        let e = read_log::<terl_wire::EvalResult>(&fifo).unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
