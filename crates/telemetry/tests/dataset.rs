//! The TEP dataset on disk: round trip, crash recovery, rejection of bad input, and the official
//! Python MCAP reader decoding our files.

use std::{
    collections::BTreeMap,
    fs,
    io::BufWriter,
    path::{Path, PathBuf},
    process::Command,
    sync::atomic::{AtomicU32, Ordering},
    time::Instant,
};

use prost::Message as _;
use terl_telemetry::{
    dataset_path, read_tep_dataset, TelemetryError, TepDataset, TepDatasetWriter, TEP_SCHEMA_NAME,
    TEP_TOPIC,
};
use terl_wire::{pb, TepSample, ACTION_DIM, OBS_DIM};

/// A fresh directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let dir = std::env::temp_dir().join(format!(
            "terl-telemetry-{name}-{}-{}",
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

/// Deterministic samples whose floats exercise awkward bit patterns (-0.0, subnormals, extremes).
fn samples(n: usize) -> Vec<TepSample> {
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let special = [
        -0.0,
        f32::MIN_POSITIVE / 3.0,
        f32::MAX,
        f32::MIN,
        1e-30,
        -1.0,
    ];
    let mut float = |i: usize| {
        let bits = next();
        if bits % 17 == 0 {
            special[i % special.len()]
        } else {
            (bits >> 40) as f32 / (1u64 << 23) as f32 * 2.0 - 1.0
        }
    };
    (0..n)
        .map(|i| {
            let obs = std::array::from_fn(|j| float(i + j));
            let next_obs = std::array::from_fn(|j| float(i + j + 1));
            let goal = std::array::from_fn(|j| float(i * 3 + j));
            let action = std::array::from_fn(|j| (float(j) * 0.5).clamp(-1.0, 1.0));
            TepSample {
                task: ["reach-v3", "door-open-v3", "pick-place-v3"][i % 3].to_owned(),
                trajectory_id: (i / 150) as u64 + (1 << 40),
                step: (i % 150) as u32,
                priority: (i as f64).sqrt() * 0.1 + 1e-9,
                obs,
                next_obs,
                goal_obs: (i % 2 == 0).then_some(goal),
                action,
                success: i % 7 == 6,
                variation: (i % 3 == 0).then_some((i % 50) as u32),
            }
        })
        .collect()
}

/// Equality on bit patterns, so -0.0 vs 0.0 or a changed NaN payload would fail.
fn assert_bit_exact(got: &[TepSample], want: &[TepSample]) {
    assert_eq!(got.len(), want.len());
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert_eq!(
            (&g.task, g.trajectory_id, g.step),
            (&w.task, w.trajectory_id, w.step),
            "sample {i}"
        );
        assert_eq!(g.priority.to_bits(), w.priority.to_bits(), "sample {i}");
        assert_eq!(bits(&g.obs), bits(&w.obs), "sample {i} obs");
        assert_eq!(bits(&g.next_obs), bits(&w.next_obs), "sample {i} next_obs");
        assert_eq!(
            g.goal_obs.map(|x| bits(&x)),
            w.goal_obs.map(|x| bits(&x)),
            "sample {i} goal_obs"
        );
        assert_eq!(bits(&g.action), bits(&w.action), "sample {i} action");
    }
}

fn log_time(i: usize) -> u64 {
    1_700_000_000_000_000_000 + i as u64 * 1_000
}

#[test]
fn round_trip_is_bit_exact() {
    let dir = TempDir::new("round-trip");
    // A nested run directory that does not exist yet: create() makes it.
    let path = dataset_path(&dir.0.join("runs/r1"));
    let want = samples(5000);
    assert!(want.iter().any(|s| s.goal_obs.is_none()) && want.iter().any(|s| s.goal_obs.is_some()));

    let start = Instant::now();
    let mut writer = TepDatasetWriter::create(&path).unwrap();
    for (i, s) in want.iter().enumerate() {
        writer.write(s, log_time(i)).unwrap();
    }
    assert_eq!(writer.messages(), 5000);
    assert_eq!(writer.finish().unwrap(), 5000);
    let write_s = start.elapsed().as_secs_f64();

    let start = Instant::now();
    let got = read_tep_dataset(&path).unwrap();
    let read_s = start.elapsed().as_secs_f64();
    let bytes = fs::metadata(&path).unwrap().len();
    eprintln!(
        "5000 samples, {bytes} bytes: write {:.0} samples/s, read {:.0} samples/s",
        5000.0 / write_s,
        5000.0 / read_s
    );
    assert_eq!((got.rejected, got.truncated), (0, false));
    assert_bit_exact(&got.samples, &want);
}

#[test]
fn create_refuses_to_overwrite_and_replace_starts_over() {
    let dir = TempDir::new("overwrite");
    let path = dataset_path(&dir.0);
    let mut writer = TepDatasetWriter::create(&path).unwrap();
    writer.write(&samples(1)[0], 1).unwrap();
    drop(writer); // Drop finishes the file.
    let got = read_tep_dataset(&path).unwrap();
    assert_eq!((got.samples.len(), got.truncated), (1, false));

    let err = TepDatasetWriter::create(&path).unwrap_err();
    assert!(matches!(err, TelemetryError::AlreadyExists { .. }), "{err}");
    assert!(err.to_string().contains("replace"), "{err}");
    assert_eq!(read_tep_dataset(&path).unwrap().samples.len(), 1);

    let writer = TepDatasetWriter::replace(&path).unwrap();
    assert_eq!(writer.finish().unwrap(), 0);
    let got = read_tep_dataset(&path).unwrap();
    assert_eq!((got.samples.len(), got.truncated), (0, false));
}

#[test]
fn killed_writer_keeps_everything_flushed() {
    let dir = TempDir::new("killed");
    let path = dataset_path(&dir.0);
    let want = samples(6000);
    let mut writer = TepDatasetWriter::create(&path).unwrap();
    let mut flushed = Vec::new(); // (samples written, file length) at each flush
    for (i, s) in want.iter().enumerate() {
        writer.write(s, log_time(i)).unwrap();
        if [1000, 4500].contains(&(i + 1)) {
            writer.flush().unwrap();
            flushed.push((i + 1, fs::metadata(&path).unwrap().len()));
        }
    }
    // A kill: no Drop, no finish. The samples after the last flush are in memory only.
    std::mem::forget(writer);
    let killed = fs::read(&path).unwrap();
    let got = read_tep_dataset(&path).unwrap();
    assert!(got.truncated);
    assert_eq!(got.rejected, 0);
    assert_bit_exact(&got.samples, &want[..4500]);

    // Cut the file anywhere after a flush: every sample before that flush survives, and whatever
    // else is read is an exact prefix of what was written.
    let (n1, len1) = flushed[0];
    let (n2, len2) = flushed[1];
    assert!(len1 < len2 && len2 as usize == killed.len(), "{flushed:?}");
    for (cut, at_least) in [
        (len1, n1),
        (len1 + 1, n1),
        (len1 + 9, n1),
        ((len1 + len2) / 2, n1),
        (len2 - 1, n1),
        (len2, n2),
    ] {
        fs::write(&path, &killed[..cut as usize]).unwrap();
        let got = read_tep_dataset(&path).unwrap();
        assert!(got.truncated, "cut at {cut}");
        assert!(
            got.samples.len() >= at_least,
            "cut at {cut}: {}",
            got.samples.len()
        );
        assert_bit_exact(&got.samples, &want[..got.samples.len()]);
    }

    // A finished file cut inside its summary or footer keeps all samples but is truncated.
    fs::remove_file(&path).unwrap();
    let mut writer = TepDatasetWriter::create(&path).unwrap();
    for (i, s) in want[..100].iter().enumerate() {
        writer.write(s, log_time(i)).unwrap();
    }
    writer.finish().unwrap();
    let full = fs::read(&path).unwrap();
    fs::write(&path, &full[..full.len() - 1]).unwrap();
    let got = read_tep_dataset(&path).unwrap();
    assert!(got.truncated);
    assert_bit_exact(&got.samples, &want[..100]);

    // Killed right after create(): the schema and channel are on disk, no samples.
    fs::remove_file(&path).unwrap();
    std::mem::forget(TepDatasetWriter::create(&path).unwrap());
    let got = read_tep_dataset(&path).unwrap();
    assert_eq!((got.samples.len(), got.truncated), (0, true));
}

#[test]
fn garbage_and_foreign_files_are_clear_errors() {
    let dir = TempDir::new("garbage");
    let missing = dir.0.join("missing.mcap");
    let err = read_tep_dataset(&missing).unwrap_err();
    assert!(matches!(err, TelemetryError::Io { .. }), "{err}");

    for (name, bytes) in [
        ("empty.mcap", Vec::new()),
        (
            "text.mcap",
            b"this is not an MCAP file at all\n".repeat(100),
        ),
    ] {
        let path = dir.0.join(name);
        fs::write(&path, bytes).unwrap();
        let err = read_tep_dataset(&path).unwrap_err();
        assert!(matches!(err, TelemetryError::NotMcap { .. }), "{err}");
        assert!(err.to_string().contains("is not an MCAP file"), "{err}");
    }

    // A valid MCAP file without our topic.
    let path = dir.0.join("other.mcap");
    raw_mcap(
        &path,
        "/other",
        TEP_SCHEMA_NAME,
        "protobuf",
        &[b"x".to_vec()],
    );
    let err = read_tep_dataset(&path).unwrap_err();
    assert!(matches!(err, TelemetryError::NoChannel { .. }), "{err}");
    assert!(err.to_string().contains("/tep/samples"), "{err}");

    // Our topic with someone else's schema.
    let path = dir.0.join("wrong-schema.mcap");
    raw_mcap(&path, TEP_TOPIC, "terl.v1.Metric", "protobuf", &[]);
    let err = read_tep_dataset(&path).unwrap_err();
    assert!(matches!(err, TelemetryError::WrongSchema { .. }), "{err}");
    assert!(err.to_string().contains("terl.v1.Metric"), "{err}");
}

#[test]
fn invalid_samples_are_counted_and_skipped() {
    let dir = TempDir::new("invalid");
    let path = dir.0.join("mixed.mcap");
    let good = samples(5);
    let encode = |m: pb::TepSample| m.encode_to_vec();
    let mut out_of_range = pb::TepSample::from(&good[0]);
    out_of_range.action[2] = 1.5;
    let mut nan = pb::TepSample::from(&good[0]);
    nan.obs[7] = f32::NAN;
    let mut short = pb::TepSample::from(&good[0]);
    short.next_obs.pop();
    let messages = vec![
        encode(pb::TepSample::from(&good[0])),
        encode(out_of_range),
        encode(pb::TepSample::from(&good[1])),
        encode(nan),
        vec![0xff, 0xff, 0xff], // not protobuf
        encode(short),
        encode(pb::TepSample::from(&good[2])),
    ];
    raw_mcap(&path, TEP_TOPIC, TEP_SCHEMA_NAME, "protobuf", &messages);
    let got = read_tep_dataset(&path).unwrap();
    assert_eq!(got.rejected, 4);
    assert!(!got.truncated);
    assert_bit_exact(&got.samples, &good[..3]);
}

/// Writes an MCAP file with one protobuf channel on `topic` (schema data: our descriptor set).
fn raw_mcap(path: &Path, topic: &str, schema: &str, encoding: &str, messages: &[Vec<u8>]) {
    let file = BufWriter::new(fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .create(file)
        .unwrap();
    let schema_id = w
        .add_schema(schema, encoding, terl_wire::FILE_DESCRIPTOR_SET)
        .unwrap();
    let channel = w
        .add_channel(schema_id, topic, "protobuf", &BTreeMap::new())
        .unwrap();
    for (i, data) in messages.iter().enumerate() {
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: i as u32,
            log_time: i as u64,
            publish_time: i as u64,
        };
        w.write_to_known_channel(&header, data).unwrap();
    }
    w.finish().unwrap();
}

fn venv_python() -> PathBuf {
    let venv = std::env::var_os("TERL_MCAP_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.deps/mcap-venv"));
    let python = venv.join("bin/python");
    assert!(
        python.exists(),
        "the Python MCAP reader venv is missing ({}); run deploy/setup.sh (or \
         crates/telemetry/tests/python/setup-venv.sh) to create it",
        python.display()
    );
    python
}

#[test]
fn official_python_reader_decodes_the_dataset() {
    let dir = TempDir::new("python");
    let path = dataset_path(&dir.0);
    let want = samples(3000);
    let mut writer = TepDatasetWriter::create(&path).unwrap();
    for (i, s) in want.iter().enumerate() {
        writer.write(s, log_time(i)).unwrap();
        if i % 1000 == 999 {
            writer.flush().unwrap(); // several chunks, some closed by flush
        }
    }
    writer.finish().unwrap();

    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/read_mcap.py");
    let output = Command::new(venv_python())
        .arg(&script)
        .arg(&path)
        .output()
        .expect("python runs");
    assert!(
        output.status.success(),
        "read_mcap.py failed: {}\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).expect("JSON report");
    let first = &want[0];
    let priority_sum: f64 = want.iter().map(|s| s.priority).sum();
    assert_eq!(report["count"], 3000, "{report}");
    assert_eq!(report["statistics_message_count"], 3000, "{report}");
    assert_eq!(report["schema_name"], "terl.v1.TepSample", "{report}");
    assert_eq!(report["schema_encoding"], "protobuf", "{report}");
    assert_eq!(report["message_encoding"], "protobuf", "{report}");
    assert_eq!(report["message_type"], "terl.v1.TepSample", "{report}");
    assert_eq!(
        report["priority_sum"].as_f64(),
        Some(priority_sum),
        "{report}"
    );
    let f = &report["first"];
    assert_eq!(f["task"], first.task.as_str(), "{report}");
    assert_eq!(f["trajectory_id"], first.trajectory_id, "{report}");
    assert_eq!(f["step"], first.step, "{report}");
    assert_eq!(f["priority"].as_f64(), Some(first.priority), "{report}");
    assert_eq!(f["obs_len"], OBS_DIM, "{report}");
    assert_eq!(f["next_obs_len"], OBS_DIM, "{report}");
    assert_eq!(f["goal_obs_len"], OBS_DIM, "{report}");
    let action: Vec<f32> = serde_json::from_value(f["action"].clone()).unwrap();
    assert_eq!(action.len(), ACTION_DIM);
    assert_eq!(action, first.action.to_vec(), "{report}");
    // And our reader agrees.
    let got: TepDataset = read_tep_dataset(&path).unwrap();
    assert_bit_exact(&got.samples, &want);
}
