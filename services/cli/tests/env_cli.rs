//! `terl env ...` as a user runs it: real binary, real files; and terl's flags in seconds with
//! extreme values.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn terl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(args)
        .output()
        .expect("run terl")
}

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures/metaworld")
        .join(name)
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn list_shows_tasks_and_sets() {
    let o = terl(&["env", "list", "--json"]);
    assert!(o.status.success(), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let tasks = v["tasks"].as_array().unwrap();
    assert_eq!(tasks.len(), 50);
    assert!(tasks.iter().any(|t| t == "reach-v3"));
    for (set, len) in [
        ("mt10", 10),
        ("mt50", 50),
        ("ml10-train", 10),
        ("ml10-test", 5),
        ("ml45-train", 45),
        ("ml45-test", 5),
        ("mt20", 20),
        ("mt1-ind", 5),
        ("mt-test", 4),
    ] {
        assert_eq!(v["task_sets"][set].as_array().unwrap().len(), len, "{set}");
    }
    assert_eq!(&v["task_sets"]["mt50"], &v["tasks"]);

    // The text listing names every task and every set.
    let o = terl(&["env", "list"]);
    assert!(o.status.success(), "{}", text(&o));
    let listing = String::from_utf8_lossy(&o.stdout);
    assert!(listing.starts_with("tasks (50):"), "{listing}");
    for t in tasks {
        assert!(listing.contains(t.as_str().unwrap()), "{t} missing");
    }
    for set in v["task_sets"].as_object().unwrap().keys() {
        assert!(
            listing.contains(&format!("  {set} ")),
            "{set} missing: {listing}"
        );
    }
}

#[test]
fn replay_then_compare_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("reach.jsonl");
    let input = fixture("reach-v3-s1.jsonl.gz");
    let o = terl(&["env", "replay", "--trace", s(&input), "--out", s(&out)]);
    assert!(o.status.success(), "{}", text(&o));
    let lines = std::fs::read_to_string(&out).unwrap();
    assert_eq!(lines.lines().count(), 502, "header + reset + 500 steps");
    let o = terl(&["env", "compare", s(&input), s(&out), "--json"]);
    assert!(o.status.success(), "{}", text(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["comparison"]["obs_max_abs"].as_f64().unwrap() < 1e-4);

    // Perturb one observation value beyond tolerance: compare must fail and say where.
    let mut rows: Vec<serde_json::Value> = lines
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let x = rows[100]["obs"][5].as_f64().unwrap();
    rows[100]["obs"][5] = serde_json::json!(x + 1e-3);
    let bad = dir.path().join("bad.jsonl");
    let body: Vec<String> = rows.iter().map(|r| r.to_string()).collect();
    std::fs::write(&bad, body.join("\n")).unwrap();
    let o = terl(&["env", "compare", s(&input), s(&bad)]);
    assert!(!o.status.success());
    let t = text(&o);
    assert!(
        t.contains("OVER TOLERANCE") && t.contains("step 99, index 5"),
        "{t}"
    );
}

#[test]
fn replay_rejects_bad_traces_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.jsonl");
    let cases = [
        (
            "{\"task\": \"reach-v9\", \"rand_vec\": [0,0.6,0.02,0,0.85,0.2]}\n{\"t\":0,\"obs\":[0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0]}\n",
            "valid tasks",
        ),
        (
            "{\"task\": \"reach-v3\", \"rand_vec\": [0,0.6]}\n{\"t\":0,\"obs\":[0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,0]}\n",
            "rand_vec has length 2, expected 6",
        ),
        ("{\"task\": \"reach-v3\", \"rand_vec\": [0,0.6,0.02,0,0.85,0.2]}\n{\"t\":0,\"obs\":[1,2]}\n", "line 2"),
        ("not json\n", "line 1"),
    ];
    for (i, (body, expect)) in cases.iter().enumerate() {
        let p = dir.path().join(format!("case{i}.jsonl"));
        std::fs::write(&p, body).unwrap();
        let o = terl(&["env", "replay", "--trace", s(&p), "--out", s(&out)]);
        assert!(!o.status.success(), "case {i} should fail");
        let t = text(&o);
        assert!(t.contains(expect), "case {i}: expected {expect:?} in {t}");
    }
}

#[test]
fn missing_assets_name_the_setup_script() {
    let o = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["env", "replay", "--trace"])
        .arg(fixture("reach-v3-s1.jsonl.gz"))
        .args(["--out", "/dev/null"])
        .env("TERL_METAWORLD_ASSETS", "/nonexistent/metaworld")
        .output()
        .unwrap();
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("deploy/setup.sh"), "{t}");
    let o = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["env", "replay", "--trace"])
        .arg(fixture("reach-v3-s1.jsonl.gz"))
        .args(["--out", "/dev/null"])
        .env("TERL_MUJOCO_LIB", "/nonexistent/libmujoco.so")
        .output()
        .unwrap();
    assert!(!o.status.success());
    let t = text(&o);
    assert!(t.contains("deploy/setup.sh"), "{t}");
}

/// `terl env list | head -0`: the reader of terl's stdout is gone before terl writes. terl ends
/// as Unix tools do (killed by SIGPIPE, no output on stderr) instead of panicking in `println!`
/// with exit code 101.
#[test]
fn a_closed_pipe_ends_terl_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().expect("pipe");
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["env", "list"])
        .stdout(writer)
        .stderr(std::process::Stdio::piped())
        .output()
        .expect("run terl");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "terl panicked: {err}");
    assert_eq!(
        out.status.signal(),
        Some(nix::sys::signal::Signal::SIGPIPE as i32),
        "terl did not end by SIGPIPE: {:?}, stderr: {err}",
        out.status
    );
}

/// Flags in seconds with extreme values are refused by the parser (exit 2, the flag named),
/// never a panic when the value becomes a `Duration`.
#[test]
fn extreme_seconds_are_refused_before_anything_runs() {
    for flag in [
        &["status", "--addr", "127.0.0.1:1", "--timeout"][..],
        &["bench", "env", "--tasks", "reach-v3", "--seconds"][..],
        &["bench", "transport", "--seconds"][..],
    ] {
        for v in ["1e300", "inf", "nan", "-1", "0", "1.8e19"] {
            // `--flag=value`, so that `-1` is a value and not a flag.
            let last = format!("{}={v}", flag[flag.len() - 1]);
            let mut args = flag[..flag.len() - 1].to_vec();
            args.push(&last);
            let o = terl(&args);
            let t = text(&o);
            assert_eq!(o.status.code(), Some(2), "{args:?}: {t}");
            assert!(!t.contains("panicked"), "{args:?}: {t}");
            assert!(t.contains(flag[flag.len() - 1]), "{args:?}: {t}");
        }
    }
}

/// `terl bench env --memory` runs its probes as child processes of `terl` itself (the hidden
/// `bench env-memory-probe`, once with no episodes): the flags it passes them must parse, and
/// the report comes out.
#[test]
fn the_memory_bench_runs_its_probes() {
    let o = terl(&[
        "bench",
        "env",
        "--memory",
        "--tasks",
        "reach-v3",
        "--envs",
        "2",
        "--episodes",
        "1",
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(report.get("floors_met").is_some(), "{report}");
}
