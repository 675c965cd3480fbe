//! `terl planner dataset | train | eval` end to end on real MuJoCo and real files: the dataset's
//! transitions are checked against a second path (the same variation reset and the recorded
//! actions replayed through `terl_sim::Env` give the recorded observations bit for bit, and
//! success ends each episode), a planner trained on it is scored, and bad input is refused.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

use std::os::unix::fs::FileTypeExt;
use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;
use terl_sim::Env;

fn terl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(o: &Output) -> String {
    assert!(
        o.status.success(),
        "terl failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn refused(o: &Output, needle: &str) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "exit code; stderr: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains(needle), "expected {needle:?} in: {err}");
}

fn p(dir: &Path, name: &str) -> String {
    dir.join(name).display().to_string()
}

/// A planner path nothing else in a test writes.
fn other_planner(dir: &Path) -> String {
    p(dir, "other.safetensors")
}

#[test]
fn dataset_replays_in_the_environment_and_a_trained_planner_is_scored() {
    let dir = tempfile::tempdir().unwrap();
    let (train, held, planner) = (
        p(dir.path(), "train.mcap"),
        p(dir.path(), "held.mcap"),
        p(dir.path(), "p.safetensors"),
    );
    let out = ok(&terl(&[
        "planner",
        "dataset",
        "--tasks",
        "reach-v3,drawer-close-v3",
        "--episodes-per-task",
        "4",
        "--variations",
        "0..4",
        "--out",
        &train,
        "--json",
    ]));
    let summary: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(summary["tasks"].as_array().unwrap().len(), 2);

    // Second path: replay the recorded actions from the recorded variation.
    let data = terl_telemetry::read_tep_dataset(&train).unwrap();
    assert!(!data.truncated && data.rejected == 0);
    let first: Vec<_> = data
        .samples
        .iter()
        .filter(|s| s.trajectory_id == data.samples[0].trajectory_id)
        .collect();
    let mut env = Env::new(&first[0].task).unwrap();
    let obs = env
        .reset_variation(0, first[0].variation.unwrap() as usize)
        .unwrap();
    assert_eq!(obs.map(|v| v as f32), first[0].obs);
    for (i, s) in first.iter().enumerate() {
        assert_eq!(s.step as usize, i);
        let step = env.step(&s.action).unwrap();
        assert_eq!(step.obs.map(|v| v as f32), s.next_obs, "step {i}");
        assert_eq!(step.success, s.success, "step {i}");
    }
    assert!(
        first.last().unwrap().success,
        "an episode ends at its first success"
    );
    assert!(first[..first.len() - 1].iter().all(|s| !s.success));

    ok(&terl(&[
        "planner",
        "dataset",
        "--tasks",
        "reach-v3,drawer-close-v3",
        "--episodes-per-task",
        "2",
        "--variations",
        "40,41",
        "--seed",
        "1",
        "--out",
        &held,
    ]));
    ok(&terl(&[
        "planner",
        "train",
        "--dataset",
        &train,
        "--eval-dataset",
        &held,
        "--updates",
        "40",
        "--eval-every",
        "20",
        "--set",
        "f_hidden=[32,32]",
        "--set",
        "an_hidden=[32,32]",
        "--set",
        "batch_size=64",
        "--out",
        &planner,
    ]));
    let log = std::fs::read_to_string(dir.path().join("p.train.jsonl")).unwrap();
    assert_eq!(log.lines().count(), 2, "one line per --eval-every updates");
    let last: Value = serde_json::from_str(log.lines().last().unwrap()).unwrap();
    assert_eq!(last["update"], 40);
    assert!(last["f_loss"].as_f64().unwrap().is_finite());

    let json_out = p(dir.path(), "eval.json");
    let table = ok(&terl(&[
        "planner",
        "eval",
        "--planner",
        &planner,
        "--dataset",
        &held,
        "--goals",
        &train,
        "--rollouts",
        "2",
        "--json-out",
        &json_out,
    ]));
    assert!(table.contains("AN alone in the environment"), "{table}");
    let e: Value = serde_json::from_str(&std::fs::read_to_string(&json_out).unwrap()).unwrap();
    let rho = e["f"]["spearman"].as_f64().unwrap();
    assert!((-1.0..=1.0).contains(&rho));
    let tasks = e["tasks"].as_array().unwrap();
    assert_eq!(tasks.len(), 2);
    for t in tasks {
        for arm in ["an_final_state", "an_replace", "random"] {
            assert_eq!(t[arm]["episodes"], 2, "{arm}");
        }
    }
    // Pairs: every pair of each held-out trajectory up to its success (all, below 200).
    let held_data = terl_telemetry::read_tep_dataset(&held).unwrap();
    let mut lens = std::collections::BTreeMap::<u64, u64>::new();
    for s in &held_data.samples {
        *lens.entry(s.trajectory_id).or_default() += 1;
    }
    let pairs: u64 = lens.values().map(|&n| (n * (n + 1) / 2).min(200)).sum();
    assert_eq!(e["f"]["pairs"].as_u64().unwrap(), pairs);

    bad_input_is_refused_and_nothing_is_overwritten(dir.path(), &train, &held, &planner);
}

/// Bad input to the three commands, given a dataset pair and a planner made by them: clear
/// errors, nothing overwritten, no partial file left.
fn bad_input_is_refused_and_nothing_is_overwritten(
    dir: &Path,
    train: &str,
    held: &str,
    planner: &str,
) {
    let (train, held, planner) = (train.to_string(), held.to_string(), planner.to_string());
    let before = std::fs::metadata(&train).unwrap().len();
    refused(
        &terl(&["planner", "dataset", "--tasks", "reach-v3", "--out", &train]),
        "already exists",
    );
    assert_eq!(std::fs::metadata(&train).unwrap().len(), before);
    // Outputs that would destroy an input, or are not files, are refused before any work.
    let small = [
        "--updates",
        "2",
        "--set",
        "f_hidden=[8]",
        "--set",
        "an_hidden=[8]",
    ];
    for (out, needle) in [
        (train.as_str(), "is also an input"),
        (held.as_str(), "is also an input"),
        ("/dev/null", "not a regular file"),
    ] {
        let mut a = vec!["planner", "train", "--dataset", &train];
        a.extend(["--eval-dataset", &held, "--out", out]);
        a.extend(small);
        refused(&terl(&a), needle);
    }
    assert_eq!(std::fs::metadata(&train).unwrap().len(), before);
    assert!(std::fs::metadata("/dev/null")
        .unwrap()
        .file_type()
        .is_char_device());
    let other_p = other_planner(dir);
    let mut a = vec![
        "planner",
        "train",
        "--dataset",
        &train,
        "--eval-dataset",
        &train,
    ];
    a.extend(["--out", &other_p]);
    refused(&terl(&a), "also a --dataset");
    let eval = [
        "planner",
        "eval",
        "--planner",
        &planner,
        "--dataset",
        &held,
        "--rollouts",
        "0",
    ];
    refused(
        &terl(&[&eval[..], &["--json-out", &planner]].concat()),
        "is also an input",
    );
    assert!(ok(&terl(&eval)).contains("F against"));
    // A damaged dataset is refused unless asked for.
    let mut bytes = std::fs::read(&held).unwrap();
    let mid = bytes.len() / 2;
    for b in &mut bytes[mid..mid + 4] {
        *b ^= 0xff;
    }
    let damaged = p(dir, "damaged.mcap");
    std::fs::write(&damaged, bytes).unwrap();
    let mut a = vec![
        "planner",
        "train",
        "--dataset",
        &train,
        "--dataset",
        &damaged,
    ];
    a.extend(["--out", &other_p]);
    a.extend(small);
    refused(&terl(&a), "damaged or incomplete");
    a.push("--accept-partial");
    ok(&terl(&a));
    // A run that writes nothing leaves nothing at --out (and no partial file).
    let none = p(dir, "none.mcap");
    refused(
        &terl(&[
            "planner",
            "dataset",
            "--tasks",
            "pick-place-v3",
            "--episodes-per-task",
            "1",
            "--noise",
            "100",
            "--variations",
            "0",
            "--out",
            &none,
        ]),
        "no episode succeeded",
    );
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("none") || n.contains(".partial"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    let other = p(dir, "x.mcap");
    for (v, needle) in [
        ("40..40", "empty range"),
        ("60", "not in 0..50"),
        ("1,1", "twice"),
        ("0..18446744073709551615", "goal variations 0..50"),
    ] {
        refused(
            &terl(&[
                "planner",
                "dataset",
                "--tasks",
                "reach-v3",
                "--variations",
                v,
                "--out",
                &other,
            ]),
            needle,
        );
    }
    refused(
        &terl(&[
            "planner",
            "train",
            "--dataset",
            &held,
            "--set",
            "f_output_scale=-1",
            "--out",
            &other,
        ]),
        "f_output_scale",
    );
    refused(
        &terl(&["planner", "eval", "--planner", &train, "--dataset", &held]),
        "planner file",
    );
}
