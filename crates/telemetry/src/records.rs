//! The run's other logs: learner metrics (`metrics.mcap`, topic `/metrics`, `terl.v1.Metric`),
//! finished episodes (`episodes.mcap`, topic `/episodes`, `terl.v1.EpisodeSummary`) and in-run
//! evaluations (`eval.mcap`, topic `/eval`, `terl.v1.EvalResult`, written by the selector's
//! evaluator). Same file layout and crash recovery as the TEP dataset (crate docs).

use std::{fmt, marker::PhantomData, path::Path};

use prost::Message as _;
use terl_wire::{pb, EpisodeSummary, EvalResult, Metric};

use crate::log::{read_channel, Channel, ProtoWriter};
use crate::Result;

/// A record type with its own channel.
pub trait LogRecord: Sized {
    #[doc(hidden)]
    type Proto: prost::Message + Default;
    #[doc(hidden)]
    const CHANNEL: Channel;
    #[doc(hidden)]
    fn to_proto(&self) -> Self::Proto;
    #[doc(hidden)]
    fn from_proto(p: Self::Proto) -> std::result::Result<Self, String>;
}

impl LogRecord for Metric {
    type Proto = pb::Metric;
    const CHANNEL: Channel = Channel {
        topic: "/metrics",
        schema: "terl.v1.Metric",
        what: "metrics log",
    };
    fn to_proto(&self) -> pb::Metric {
        pb::Metric::from(self.clone())
    }
    fn from_proto(p: pb::Metric) -> std::result::Result<Self, String> {
        Metric::try_from(p).map_err(|s| s.message().to_owned())
    }
}

impl LogRecord for EpisodeSummary {
    type Proto = pb::EpisodeSummary;
    const CHANNEL: Channel = Channel {
        topic: "/episodes",
        schema: "terl.v1.EpisodeSummary",
        what: "episode log",
    };
    fn to_proto(&self) -> pb::EpisodeSummary {
        pb::EpisodeSummary::from(self.clone())
    }
    fn from_proto(p: pb::EpisodeSummary) -> std::result::Result<Self, String> {
        EpisodeSummary::try_from(p).map_err(|s| s.message().to_owned())
    }
}

impl LogRecord for EvalResult {
    type Proto = pb::EvalResult;
    const CHANNEL: Channel = Channel {
        topic: "/eval",
        schema: "terl.v1.EvalResult",
        what: "evaluation log",
    };
    fn to_proto(&self) -> pb::EvalResult {
        pb::EvalResult::from(self.clone())
    }
    fn from_proto(p: pb::EvalResult) -> std::result::Result<Self, String> {
        EvalResult::try_from(p).map_err(|s| s.message().to_owned())
    }
}

/// Appends records of one type to a new MCAP file; flush to make them survive a kill, finish
/// (or drop) to write the summary.
pub struct LogWriter<R: LogRecord> {
    inner: ProtoWriter,
    _record: PhantomData<fn(&R)>,
}

/// `runs/<id>/metrics.mcap`.
pub type MetricsWriter = LogWriter<Metric>;
/// `runs/<id>/episodes.mcap`.
pub type EpisodeLogWriter = LogWriter<EpisodeSummary>;
/// `runs/<id>/eval.mcap`: one `terl.v1.EvalResult` per in-run evaluation.
pub type EvalLogWriter = LogWriter<EvalResult>;

impl<R: LogRecord> fmt::Debug for LogWriter<R> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LogWriter")
            .field("topic", &R::CHANNEL.topic)
            .field("path", &self.inner.path())
            .field("messages", &self.inner.messages())
            .finish_non_exhaustive()
    }
}

impl<R: LogRecord> LogWriter<R> {
    /// Creates the file (never overwrites: [`crate::TelemetryError::AlreadyExists`]).
    pub fn create(path: impl AsRef<Path>) -> Result<Self> {
        Ok(Self {
            inner: ProtoWriter::open(path.as_ref(), R::CHANNEL, false)?,
            _record: PhantomData,
        })
    }

    /// The file this writer appends to.
    pub fn path(&self) -> &Path {
        self.inner.path()
    }

    /// Records written so far.
    pub fn messages(&self) -> u64 {
        self.inner.messages()
    }

    /// Appends one record with log time `log_time_ns` (nanoseconds since the Unix epoch).
    pub fn write(&mut self, record: &R, log_time_ns: u64) -> Result<()> {
        self.inner.write(&record.to_proto(), log_time_ns)
    }

    /// Closes the current chunk and hands everything written so far to the operating system: from
    /// now on a crash or kill of this process cannot lose those records.
    pub fn flush(&mut self) -> Result<()> {
        self.inner.flush()
    }

    /// Writes the summary and footer, syncs, returns the message count.
    pub fn finish(mut self) -> Result<u64> {
        self.inner.finish()
    }
}

/// The records of a log file.
#[derive(Debug, Clone, PartialEq)]
pub struct Logged<R> {
    /// The records that decoded and validated, in file order.
    pub records: Vec<R>,
    /// Messages that did not decode or failed validation (skipped).
    pub rejected: u64,
    /// Reading stopped before the end of a complete file (its writer was killed, the file was
    /// cut, or it is damaged): `records` is what came before that point.
    pub truncated: bool,
    /// Why reading stopped, in words (a cut, a record claiming more bytes than the file has, a
    /// chunk whose CRC does not match, …): `Some` exactly when `truncated` is set.
    pub truncation: Option<String>,
}

/// Reads every record of type `R` from its channel in the MCAP file at `path`.
///
/// Records that do not decode or validate are counted in [`Logged::rejected`] and skipped. A file
/// that ends early or is damaged part-way (a cut, a damaged record length, a flipped byte in a
/// chunk) yields the records before that point with [`Logged::truncated`] set and the reason in
/// [`Logged::truncation`]; no length read from the file is trusted beyond the file's size.
/// Errors: the file cannot be read, is not MCAP, has no channel of `R`, or that channel's schema
/// or encoding is wrong.
pub fn read_log<R: LogRecord>(path: impl AsRef<Path>) -> Result<Logged<R>> {
    let read = read_channel(path.as_ref(), R::CHANNEL, |bytes| {
        R::Proto::decode(bytes)
            .map_err(|e| format!("protobuf decode failed: {e}"))
            .and_then(R::from_proto)
    })?;
    Ok(Logged {
        records: read.items,
        rejected: read.rejected,
        truncated: read.stopped.is_some(),
        truncation: read.stopped,
    })
}

/// Every record of a run's `<kind>.mcap` log and its restarted segments (`<kind>.2.mcap`, …,
/// [`crate::existing_paths`]), in order, with the segments read only in part and those past a
/// missing segment (not read, [`RunLog::unread`]).
///
/// Errors: as [`read_log`], for the first segment that cannot be read at all.
pub fn read_run_log<R: LogRecord>(run_dir: &Path, kind: &str) -> Result<RunLog<R>> {
    let mut log = RunLog {
        records: Vec::new(),
        cut: Vec::new(),
        unread: Vec::new(),
    };
    let paths = crate::existing_paths(run_dir, kind);
    log.unread = crate::segments_after_gap(run_dir, kind, paths.len() as u64);
    for path in paths {
        let segment = read_log::<R>(&path)?;
        if let Some(reason) = segment.truncation {
            log.cut.push(CutSegment {
                path,
                reason,
                kept: segment.records.len(),
            });
        }
        log.records.extend(segment.records);
    }
    Ok(log)
}

/// The records of one kind of a run's log over all its segments ([`read_run_log`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RunLog<R> {
    /// The records of every segment, in segment and file order.
    pub records: Vec<R>,
    /// The segments read only in part (a stopped writer, a cut or damage).
    pub cut: Vec<CutSegment>,
    /// Segments past a missing one (`<kind>.3.mcap` without `<kind>.2.mcap`), in segment order:
    /// not read, since their place in the run is unknown; a report names them.
    pub unread: Vec<std::path::PathBuf>,
}

impl<R> RunLog<R> {
    /// One note per segment of the run that was not read in full or at all: the
    /// [`CutSegment`]s, then the [`RunLog::unread`] segments past a gap.
    pub fn notes(&self) -> Vec<String> {
        let mut notes: Vec<String> = self.cut.iter().map(ToString::to_string).collect();
        notes.extend(self.unread.iter().map(|p| crate::unread_segment_note(p)));
        notes
    }
}

/// A log segment read only in part.
#[derive(Debug, Clone, PartialEq)]
pub struct CutSegment {
    /// The segment's file.
    pub path: std::path::PathBuf,
    /// Why reading stopped ([`Logged::truncation`]).
    pub reason: String,
    /// Records kept from before that point.
    pub kept: usize,
}

impl std::fmt::Display for CutSegment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "note: {} is read only in part: {}; using the {} records before that point",
            self.path.display(),
            self.reason,
            self.kept
        )
    }
}

/// Where a run keeps its learner metrics: `run_dir/metrics.mcap`.
pub fn metrics_path(run_dir: &Path) -> std::path::PathBuf {
    run_dir.join("metrics.mcap")
}

/// Where a run keeps its episode log: `run_dir/episodes.mcap`.
pub fn episodes_path(run_dir: &Path) -> std::path::PathBuf {
    run_dir.join("episodes.mcap")
}

/// Where a run keeps its in-run evaluations: `run_dir/eval.mcap`.
pub fn eval_path(run_dir: &Path) -> std::path::PathBuf {
    run_dir.join("eval.mcap")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_and_episodes_round_trip_and_do_not_mix() {
        let dir = std::env::temp_dir().join(format!("terl-records-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut m = MetricsWriter::create(metrics_path(&dir)).unwrap();
        let metrics: Vec<Metric> = (0..300)
            .map(|i| Metric {
                name: format!("guidance/rate/task-{}", i % 3),
                value: f64::from(i) * 0.5,
                step: i as u64,
                unix_time_nanos: 1_000 + i as u64,
            })
            .collect();
        for x in &metrics {
            m.write(x, x.unix_time_nanos).unwrap();
        }
        m.flush().unwrap();
        assert_eq!(m.finish().unwrap(), 300);
        let got = read_log::<Metric>(metrics_path(&dir)).unwrap();
        assert_eq!(
            (got.records, got.rejected, got.truncated),
            (metrics, 0, false)
        );

        let mut e = EpisodeLogWriter::create(episodes_path(&dir)).unwrap();
        let ep = EpisodeSummary {
            task: "reach-v3".into(),
            actor_id: 1,
            episode_index: 4,
            episode_return: 12.5,
            success: true,
            length: 500,
            policy_version: 9,
            guided_steps: 7,
            missed_before: 2,
        };
        e.write(&ep, 5).unwrap();
        drop(e);
        assert_eq!(
            read_log::<EpisodeSummary>(episodes_path(&dir))
                .unwrap()
                .records,
            vec![ep]
        );
        // A metrics file is not an episode log: a clear error, not an empty result.
        let err = read_log::<EpisodeSummary>(metrics_path(&dir)).unwrap_err();
        assert!(err.to_string().contains("/episodes"), "{err}");
        assert!(MetricsWriter::create(metrics_path(&dir)).is_err());

        let mut w = EvalLogWriter::create(eval_path(&dir)).unwrap();
        let ev = EvalResult {
            policy_version: 300,
            env_steps: 12_000,
            episodes_per_task: 10,
            mean_success_rate: 0.5,
            mean_return: 42.0,
            tasks: vec![terl_wire::TaskEval {
                task: "reach-v3".into(),
                success_rate: 0.5,
                mean_return: 42.0,
                mean_first_success_step: Some(77.5),
                episodes: 10,
            }],
            wall_seconds: 3.0,
            cpu_seconds: 2.5,
            unix_time_nanos: 9,
        };
        w.write(&ev, 9).unwrap();
        assert_eq!(w.finish().unwrap(), 1);
        assert_eq!(
            read_log::<EvalResult>(eval_path(&dir)).unwrap().records,
            vec![ev]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    fn metric(step: u64) -> Metric {
        Metric {
            name: "loss/critic".into(),
            value: step as f64,
            step,
            unix_time_nanos: step,
        }
    }

    fn write_segment(path: std::path::PathBuf, steps: std::ops::Range<u64>) {
        let mut w = MetricsWriter::create(path).unwrap();
        for s in steps {
            w.write(&metric(s), s).unwrap();
        }
        w.finish().unwrap();
    }

    #[test]
    fn a_segment_past_a_missing_one_is_named_not_read() {
        let dir = std::env::temp_dir().join(format!("terl-segments-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        write_segment(dir.join("metrics.mcap"), 0..3);
        write_segment(dir.join("metrics.4.mcap"), 10..12);
        write_segment(dir.join("metrics.3.mcap"), 7..9);
        // Names that only look like segments are not segments.
        for name in [
            "metrics.x.mcap",
            "metrics.2.mcap.part",
            "metrics.05.mcap",
            "metrics.+6.mcap",
            "metrics.99999999999999999999.mcap",
        ] {
            std::fs::write(dir.join(name), b"").unwrap();
        }
        let log = read_run_log::<Metric>(&dir, "metrics").unwrap();
        assert_eq!(log.records, (0..3).map(metric).collect::<Vec<_>>());
        assert_eq!(
            log.unread,
            vec![dir.join("metrics.3.mcap"), dir.join("metrics.4.mcap")]
        );
        let notes = log.notes();
        assert_eq!(notes.len(), 2);
        assert!(notes[0].contains("metrics.3.mcap is not read"), "{notes:?}");
        assert_eq!(
            crate::unread_segments(&dir, "metrics"),
            log.unread,
            "the same segments without reading the log"
        );
        // Without the first segment nothing is read and every numbered one is named.
        std::fs::rename(dir.join("metrics.mcap"), dir.join("first.mcap")).unwrap();
        assert_eq!(crate::unread_segments(&dir, "metrics").len(), 2);
        std::fs::rename(dir.join("first.mcap"), dir.join("metrics.mcap")).unwrap();
        // With the gap filled every segment is read, in order.
        write_segment(dir.join("metrics.2.mcap"), 3..7);
        let log = read_run_log::<Metric>(&dir, "metrics").unwrap();
        assert!(log.unread.is_empty() && log.notes().is_empty());
        let steps: Vec<u64> = log.records.iter().map(|m| m.step).collect();
        assert_eq!(steps, vec![0, 1, 2, 3, 4, 5, 6, 7, 8, 10, 11]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
