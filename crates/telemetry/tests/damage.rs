//! Damaged MCAP logs: a damaged record length, a flipped byte or a cut anywhere never crashes
//! the readers or makes them allocate what the file does not hold; they keep the messages
//! before the damage and say what stopped them, or refuse the file with a clear error.
//!
//! Each file is written by the crate's own writers; the damage is done to its bytes.

use std::{
    fs,
    path::{Path, PathBuf},
    sync::{
        atomic::{AtomicU64, Ordering},
        OnceLock,
    },
};

use proptest::prelude::*;
use terl_telemetry::{
    read_log, read_tep_dataset, Logged, MetricsWriter, TelemetryError, TepDataset, TepDatasetWriter,
};
use terl_wire::{Metric, TepSample};

const CHUNK: u8 = 0x06;
const MESSAGE_INDEX: u8 = 0x07;

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let dir = std::env::temp_dir().join(format!(
            "terl-damage-{name}-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
    }
}

/// A top-level record of an MCAP file: where it starts, its opcode and stated body length.
#[derive(Debug, Clone, Copy)]
struct Rec {
    at: usize,
    opcode: u8,
    len: u64,
}

impl Rec {
    fn end(&self) -> usize {
        self.at + 9 + self.len as usize
    }
}

/// The top-level records after the leading magic of an intact file.
fn records(bytes: &[u8]) -> Vec<Rec> {
    let mut out = Vec::new();
    let mut at = 8;
    while at + 9 <= bytes.len() {
        let opcode = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        let rec = Rec { at, opcode, len };
        if rec.end() > bytes.len() {
            break;
        }
        out.push(rec);
        at = rec.end();
    }
    out
}

fn metric(i: usize) -> Metric {
    Metric {
        name: format!("loss/task-{}", i % 3),
        value: i as f64 * 0.25 - 3.0,
        step: i as u64,
        unix_time_nanos: 1_000 + i as u64,
    }
}

fn sample(i: usize) -> TepSample {
    let v = |k: usize| ((i * 31 + k) % 97) as f32 / 97.0 - 0.5;
    TepSample {
        task: ["reach-v3", "door-open-v3"][i % 2].to_owned(),
        trajectory_id: (i / 20) as u64,
        step: (i % 20) as u32,
        priority: 0.5 + i as f64,
        obs: std::array::from_fn(v),
        next_obs: std::array::from_fn(|k| v(k + 1)),
        goal_obs: i
            .is_multiple_of(3)
            .then(|| std::array::from_fn(|k| v(k + 2))),
        action: std::array::from_fn(|k| v(k) * 0.5),
        success: i % 5 == 4,
        variation: i.is_multiple_of(2).then_some((i % 50) as u32),
    }
}

/// Messages per chunk of the files below: every log is written in chunks of this many
/// messages (flushed), after a first chunk holding the schema and channel.
const PER_CHUNK: usize = 40;
const CHUNKS: usize = 4;
const TOTAL: usize = PER_CHUNK * CHUNKS;

/// A finished metrics log of [`TOTAL`] metrics in [`CHUNKS`] flushed chunks, as bytes.
fn metrics_file() -> &'static [u8] {
    static FILE: OnceLock<Vec<u8>> = OnceLock::new();
    FILE.get_or_init(|| {
        let dir = TempDir::new("metrics-source");
        let path = dir.0.join("metrics.mcap");
        let mut w = MetricsWriter::create(&path).unwrap();
        for i in 0..TOTAL {
            w.write(&metric(i), 1_000 + i as u64).unwrap();
            if (i + 1).is_multiple_of(PER_CHUNK) {
                w.flush().unwrap();
            }
        }
        w.finish().unwrap();
        fs::read(&path).unwrap()
    })
}

/// A finished TEP dataset of [`TOTAL`] samples in [`CHUNKS`] flushed chunks, as bytes.
fn dataset_file() -> &'static [u8] {
    static FILE: OnceLock<Vec<u8>> = OnceLock::new();
    FILE.get_or_init(|| {
        let dir = TempDir::new("dataset-source");
        let path = dir.0.join("tep-dataset.mcap");
        let mut w = TepDatasetWriter::create(&path).unwrap();
        for i in 0..TOTAL {
            w.write(&sample(i), 1_000 + i as u64).unwrap();
            if (i + 1).is_multiple_of(PER_CHUNK) {
                w.flush().unwrap();
            }
        }
        w.finish().unwrap();
        fs::read(&path).unwrap()
    })
}

/// The chunks of an intact log file: the first holds schema and channel, chunk `k` (1-based
/// after it) the messages `(k - 1) * PER_CHUNK ..k * PER_CHUNK`.
fn chunks(bytes: &[u8]) -> Vec<Rec> {
    let chunks: Vec<Rec> = records(bytes)
        .into_iter()
        .filter(|r| r.opcode == CHUNK)
        .collect();
    assert_eq!(chunks.len(), CHUNKS + 1, "{chunks:?}");
    chunks
}

/// Messages certainly intact in a file damaged only at or after byte `at`: those of the chunks
/// that end before it.
fn intact_before(bytes: &[u8], at: usize) -> usize {
    chunks(bytes)[1..]
        .iter()
        .take_while(|c| c.end() <= at)
        .count()
        * PER_CHUNK
}

fn read_metrics(path: &Path) -> terl_telemetry::Result<Logged<Metric>> {
    read_log::<Metric>(path)
}

/// What a damaged file gave: `Ok(n)` for a prefix of `n` messages, or the error.
type Outcome = Result<usize, TelemetryError>;

/// Writes `bytes` to a fresh file and reads it as a metrics log and as a TEP dataset (each
/// reader on its own file kind), checking the readers' contract on the way: what is read is an
/// exact prefix of what was written, and `truncated` is set, with a reason, whenever it is not
/// everything.
fn read_damaged(kind: Kind, bytes: &[u8]) -> Outcome {
    let dir = TempDir::new("case");
    let path = dir.0.join("damaged.mcap");
    fs::write(&path, bytes).unwrap();
    match kind {
        Kind::Metrics => {
            let log = read_metrics(&path)?;
            let want: Vec<Metric> = (0..TOTAL).map(metric).collect();
            check_prefix(&log.records, &want, log.truncated, &log.truncation);
            Ok(log.records.len())
        }
        Kind::Dataset => {
            let data: TepDataset = read_tep_dataset(&path)?;
            let want: Vec<TepSample> = (0..TOTAL).map(sample).collect();
            check_prefix(&data.samples, &want, data.truncated, &data.truncation);
            Ok(data.samples.len())
        }
    }
}

fn check_prefix<T: PartialEq + std::fmt::Debug>(
    got: &[T],
    want: &[T],
    truncated: bool,
    truncation: &Option<String>,
) {
    assert!(got.len() <= want.len());
    assert!(
        got == &want[..got.len()],
        "not a prefix of what was written"
    );
    assert_eq!(truncated, truncation.is_some(), "{truncation:?}");
    if got.len() < want.len() {
        assert!(
            truncated,
            "{} of {} messages without a word",
            got.len(),
            want.len()
        );
    }
}

/// An error that names the problem (never an I/O error: the file is there).
fn assert_clear(err: &TelemetryError) {
    assert!(
        matches!(
            err,
            TelemetryError::NotMcap { .. }
                | TelemetryError::NoChannel { .. }
                | TelemetryError::WrongSchema { .. }
        ),
        "{err}"
    );
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    Metrics,
    Dataset,
}

impl Kind {
    fn file(self) -> &'static [u8] {
        match self {
            Kind::Metrics => metrics_file(),
            Kind::Dataset => dataset_file(),
        }
    }
}

/// Lengths a damaged record might claim: far past any file, the largest values, just past the
/// end of the file.
const HUGE: [u64; 6] = [
    u64::MAX,
    0xfff0_0000_0000_0000,
    // Below isize::MAX: an allocation of this size is attempted rather than refused outright.
    4 << 60,
    1 << 40,
    u32::MAX as u64 + 1,
    0,
];

/// The damage of the original failure: a chunk's record length set to a multi-exabyte value
/// made `terl report` and the `--tep-dataset` loader abort on the allocation.
#[test]
fn damaged_record_length_keeps_the_messages_before_it() {
    for kind in [Kind::Metrics, Kind::Dataset] {
        let file = kind.file();
        let third = chunks(file)[3];
        let past_end = (file.len() - third.at) as u64;
        for len in HUGE.into_iter().filter(|&l| l != 0).chain([past_end]) {
            let mut bytes = file.to_vec();
            bytes[third.at + 1..third.at + 9].copy_from_slice(&len.to_le_bytes());
            let dir = TempDir::new("length");
            let path = dir.0.join("damaged.mcap");
            fs::write(&path, &bytes).unwrap();
            let (n, truncated, reason) = match kind {
                Kind::Metrics => {
                    let l = read_metrics(&path).unwrap();
                    assert_eq!(
                        l.records,
                        (0..2 * PER_CHUNK).map(metric).collect::<Vec<_>>()
                    );
                    (l.records.len(), l.truncated, l.truncation)
                }
                Kind::Dataset => {
                    let d = read_tep_dataset(&path).unwrap();
                    assert_eq!(
                        d.samples,
                        (0..2 * PER_CHUNK).map(sample).collect::<Vec<_>>()
                    );
                    (d.samples.len(), d.truncated, d.truncation)
                }
            };
            assert_eq!(n, 2 * PER_CHUNK, "{kind:?}, length {len}");
            assert!(truncated);
            let reason = reason.unwrap();
            if len > file.len() as u64 {
                assert!(
                    reason.contains(&format!("claims {len} bytes"))
                        && reason.contains("whole file"),
                    "{reason}"
                );
            } else {
                // Within the file's size but past its end: indistinguishable from a cut.
                assert!(reason.contains("ends inside a record"), "{reason}");
            }
        }
    }
}

/// A message's length inside a chunk: the chunk's CRC no longer matches, so none of that
/// chunk's messages is used and the read stops there.
#[test]
fn damaged_length_inside_a_chunk_fails_its_crc() {
    let file = metrics_file();
    let second = chunks(file)[2];
    // The chunk's records start after its header; find the first message record (opcode 0x05)
    // by its position: header = 8+8+8+4 + (4 + 0) + 8 bytes after the record's 9-byte prefix.
    let records_at = second.at + 9 + 8 + 8 + 8 + 4 + 4 + 8;
    assert_eq!(
        file[records_at], 0x05,
        "first record of the chunk is a message"
    );
    for len in HUGE {
        let mut bytes = file.to_vec();
        bytes[records_at + 1..records_at + 9].copy_from_slice(&len.to_le_bytes());
        let n = read_damaged(Kind::Metrics, &bytes).unwrap();
        assert_eq!(n, PER_CHUNK, "length {len}");
    }
}

/// A chunk whose opcode is damaged into one the reader skips (a message index) would drop its
/// messages silently; the writer's message numbering shows the gap, and the read stops there.
#[test]
fn a_chunk_lost_to_a_damaged_opcode_is_noticed() {
    let file = metrics_file();
    let second = chunks(file)[2];
    let mut bytes = file.to_vec();
    bytes[second.at] = MESSAGE_INDEX;
    let dir = TempDir::new("opcode");
    let path = dir.0.join("damaged.mcap");
    fs::write(&path, &bytes).unwrap();
    let log = read_metrics(&path).unwrap();
    assert_eq!(log.records, (0..PER_CHUNK).map(metric).collect::<Vec<_>>());
    let reason = log.truncation.unwrap();
    assert!(reason.contains("lost"), "{reason}");
}

/// The header's string lengths are read before anything else: a damaged one is a clear
/// "not an MCAP file", not a 4 GiB reservation.
#[test]
fn damaged_header_string_length_is_a_clear_error() {
    let file = metrics_file();
    let header = records(file)[0];
    assert_eq!(header.opcode, 0x01);
    for len in [u32::MAX, 1 << 31, header.len as u32] {
        let mut bytes = file.to_vec();
        // The header body is profile (u32 length + bytes), then library.
        bytes[header.at + 9..header.at + 13].copy_from_slice(&len.to_le_bytes());
        let err = read_damaged(Kind::Metrics, &bytes).unwrap_err();
        assert!(matches!(err, TelemetryError::NotMcap { .. }), "{err}");
        assert!(err.to_string().contains("string longer"), "{err}");
    }
}

/// One change to a file's bytes.
#[derive(Debug, Clone)]
enum Damage {
    /// Keep only the first `at` bytes (a fraction of the file, in millionths).
    Cut { at: u32 },
    /// XOR one byte with a non-zero mask.
    Flip { at: u32, mask: u8 },
    /// Set the length of top-level record `index` (modulo the count) to a huge value.
    RecordLength { index: usize, len: u64 },
    /// Write a little-endian u64 anywhere (a damaged length or offset inside a record).
    Word { at: u32, value: u64 },
}

fn position(fraction: u32, len: usize) -> usize {
    (fraction as u64 * len as u64 / 1_000_000) as usize
}

/// Applies `damage` to `bytes`; returns the first byte it changed.
fn apply(damage: &Damage, bytes: &mut Vec<u8>) -> usize {
    match *damage {
        Damage::Cut { at } => {
            let at = position(at, bytes.len());
            bytes.truncate(at);
            at
        }
        Damage::Flip { at, mask } => {
            let at = position(at, bytes.len() - 1);
            bytes[at] ^= mask;
            at
        }
        Damage::RecordLength { index, len } => {
            let recs = records(bytes);
            let Some(&rec) = recs.get(index % recs.len().max(1)) else {
                return 0;
            };
            bytes[rec.at + 1..rec.at + 9].copy_from_slice(&len.to_le_bytes());
            rec.at
        }
        Damage::Word { at, value } => {
            let at = position(at, bytes.len() - 8);
            bytes[at..at + 8].copy_from_slice(&value.to_le_bytes());
            at
        }
    }
}

fn damage() -> impl Strategy<Value = Damage> {
    let huge = prop_oneof![
        proptest::sample::select(HUGE.to_vec()),
        any::<u64>(),
        (1u64 << 32)..(1u64 << 63),
    ];
    prop_oneof![
        (0u32..1_000_000).prop_map(|at| Damage::Cut { at }),
        (0u32..1_000_000, 1u8..=255).prop_map(|(at, mask)| Damage::Flip { at, mask }),
        (any::<usize>(), huge.clone()).prop_map(|(index, len)| Damage::RecordLength { index, len }),
        (0u32..1_000_000, huge).prop_map(|(at, value)| Damage::Word { at, value }),
    ]
}

fn kind() -> impl Strategy<Value = Kind> {
    prop_oneof![Just(Kind::Metrics), Just(Kind::Dataset)]
}

/// A fixed seed: the same cases on every run, so a failure is reproducible and CI is stable.
fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x7e71_0005),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config(300))]

    /// One cut, flipped byte or huge length anywhere: an exact prefix of what was written, with
    /// every message of the chunks wholly before the damage, and `truncated` whenever
    /// something is missing; or a clear error.
    #[test]
    fn one_damage_keeps_a_prefix_or_is_a_clear_error(kind in kind(), damage in damage()) {
        let file = kind.file();
        let mut bytes = file.to_vec();
        let at = apply(&damage, &mut bytes);
        match read_damaged(kind, &bytes) {
            Ok(n) => {
                let intact = intact_before(file, at);
                prop_assert!(n >= intact, "{n} messages kept, {intact} were before the damage");
            }
            Err(err) => {
                assert_clear(&err);
                // Only damage to what comes before the first message can lose them all.
                prop_assert!(at < chunks(file)[1].at, "{err} for damage at byte {at}");
            }
        }
    }

    /// Several damages at once: still an exact prefix or a clear error, never a crash.
    #[test]
    fn several_damages_never_crash(
        kind in kind(),
        damages in proptest::collection::vec(damage(), 2..6),
    ) {
        let mut bytes = kind.file().to_vec();
        for d in &damages {
            if bytes.len() < 16 {
                break;
            }
            apply(d, &mut bytes);
        }
        if let Err(err) = read_damaged(kind, &bytes) {
            assert_clear(&err);
        }
    }
}

/// The last chunk lost to a damaged opcode leaves no gap in the numbering after it: an opcode
/// the writer never writes, or (for an opcode it does write) the statistics of the finished
/// file, still show the loss.
#[test]
fn a_last_chunk_lost_to_a_damaged_opcode_is_noticed() {
    let file = metrics_file();
    let last = chunks(file)[CHUNKS];
    for (opcode, says) in [(0xff, "never writes"), (MESSAGE_INDEX, "statistics count")] {
        let mut bytes = file.to_vec();
        bytes[last.at] = opcode;
        let dir = TempDir::new("last-opcode");
        let path = dir.0.join("damaged.mcap");
        fs::write(&path, &bytes).unwrap();
        let log = read_metrics(&path).unwrap();
        let kept = (CHUNKS - 1) * PER_CHUNK;
        assert_eq!(log.records, (0..kept).map(metric).collect::<Vec<_>>());
        let reason = log.truncation.unwrap();
        assert!(reason.contains(says), "{reason}");
    }
}
