//! TensorBoard event files of [`terl_telemetry::EventWriter`] read by TensorBoard's own reader
//! (`event_accumulator`, in `.deps/tensorboard-venv`, made by `deploy/setup.sh`): every scalar
//! back at its step and value, a second writer's file in the same folder, and a torn last record
//! (what a killed writer leaves) losing only that record.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use terl_telemetry::EventWriter;

fn python() -> PathBuf {
    let p =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.deps/tensorboard-venv/bin/python");
    assert!(
        p.exists(),
        "{} is missing: run ./deploy/setup.sh (or crates/telemetry/tests/python/setup-tensorboard-venv.sh)",
        p.display()
    );
    p
}

/// tag → [(step, value)] as TensorBoard reads `dir` (non-finite values as NaN / ±inf).
fn read(dir: &Path) -> (BTreeMap<String, Vec<(u64, f64)>>, u64) {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/read_tensorboard.py");
    let o = Command::new(python())
        .arg(script)
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "TensorBoard's reader failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let mut out = BTreeMap::new();
    for (tag, points) in v["tags"].as_object().unwrap() {
        let pts = points
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                let value = match &p[1] {
                    serde_json::Value::String(s) => s.parse::<f64>().unwrap(),
                    n => n.as_f64().unwrap(),
                };
                (p[0].as_u64().unwrap(), value)
            })
            .collect();
        out.insert(tag.clone(), pts);
    }
    (out, v["files"].as_u64().unwrap())
}

fn value_at(step: u64) -> f64 {
    // Distinct per step, negative and zero included, not representable exactly in f32.
    (step as f64 - 10.0) * 0.1
}

#[test]
fn tensorboard_reads_every_scalar_at_its_step() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = EventWriter::create(dir.path(), "learner").unwrap();
    for step in 0..40u64 {
        let mut values = vec![("charts/a", value_at(step)), ("losses/b", -(step as f64))];
        if step == 7 {
            values.push(("x/special", f64::NAN));
        }
        if step == 8 {
            values.push(("x/special", f64::INFINITY));
        }
        w.scalars(step * 1000, 1.7e9 + step as f64, values).unwrap();
    }
    assert_eq!(w.events(), 41);
    // A second writer in the same folder and second (a restarted process): its own file.
    let mut w2 = EventWriter::create(dir.path(), "learner").unwrap();
    assert_ne!(w.path(), w2.path());
    w2.scalars(40_000, 1.8e9, [("charts/a", 4.5)]).unwrap();
    drop((w, w2));

    let (tags, files) = read(dir.path());
    assert_eq!(files, 2);
    let a = &tags["charts/a"];
    assert_eq!(a.len(), 41, "{a:?}");
    for (i, (step, v)) in a.iter().take(40).enumerate() {
        assert_eq!(*step, i as u64 * 1000);
        assert_eq!(*v, f64::from(value_at(i as u64) as f32), "step {step}");
    }
    assert_eq!(a[40], (40_000, 4.5));
    assert_eq!(tags["losses/b"][39], (39_000, -39.0));
    let special = &tags["x/special"];
    assert!(
        special[0].1.is_nan() && special[1].1 == f64::INFINITY,
        "{special:?}"
    );
}

#[test]
fn a_torn_last_record_loses_only_that_record() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = EventWriter::create(dir.path(), "evaluator").unwrap();
    for step in 0..10u64 {
        w.scalars(step, 0.0, [("eval/mean_success_rate", step as f64 / 10.0)])
            .unwrap();
    }
    let path = w.path().to_owned();
    drop(w);
    // Cut inside the last record (its payload CRC and part of the payload): a kill mid-write.
    let len = std::fs::metadata(&path).unwrap().len();
    let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
    f.set_len(len - 6).unwrap();
    let (tags, _) = read(dir.path());
    let steps: Vec<u64> = tags["eval/mean_success_rate"].iter().map(|p| p.0).collect();
    assert_eq!(steps, (0..9).collect::<Vec<_>>());
}

#[test]
fn an_unwritable_folder_is_an_io_error() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not-a-folder");
    std::fs::write(&file, b"x").unwrap();
    let err = EventWriter::create(&file, "learner").unwrap_err();
    assert!(err.to_string().contains("not-a-folder"), "{err}");
}
