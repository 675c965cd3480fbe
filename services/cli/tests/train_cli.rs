//! `terl train` end to end on the smoke config: real Meta-World, real MTSAC, real files.

use std::path::PathBuf;
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[test]
fn smoke_run_writes_progress_checkpoints_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let o = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["train", "--config"])
        .arg(root().join("deploy/configs/smoke.toml"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let progress = std::fs::read_to_string(out.join("progress.jsonl")).unwrap();
    let last: serde_json::Value =
        serde_json::from_str(progress.lines().last().expect("progress lines")).unwrap();
    assert_eq!(last["env_steps"].as_u64(), Some(4000));
    assert!(last["updates"].as_u64().unwrap() > 1000, "{last}");
    assert!(last["eval"]["episodes"].as_u64().unwrap() >= 2, "{last}");
    assert!(
        out.join("checkpoints/final.safetensors")
            .metadata()
            .unwrap()
            .len()
            > 10_000
    );
    let cfg = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(
        cfg.contains("num_tasks = 2"),
        "resolved config records the task count: {cfg}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert!(report["final_progress"].is_object());
}

#[test]
fn malformed_configs_fail_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("tasks = \"mt10\"\nnum_envs = 0\n", "num_envs"),
        ("tasks = \"mt11\"\nnum_envs = 2\n", "mt11"),
        (
            "tasks = \"reach-v3\"\nnum_envs = 2\n[sac]\nbatch_size = 0\n",
            "batch_size",
        ),
        ("tasks = \"reach-v3\"\nnum_envs = 2\nbogus = 1\n", "bogus"),
        ("tasks = [1, 2\n", "invalid config"),
    ];
    for (i, (body, expect)) in cases.iter().enumerate() {
        let p = dir.path().join(format!("c{i}.toml"));
        std::fs::write(&p, body).unwrap();
        let o = Command::new(env!("CARGO_BIN_EXE_terl"))
            .args(["train", "--config"])
            .arg(&p)
            .arg("--out")
            .arg(dir.path().join(format!("out{i}")))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "case {i} should fail");
        assert!(
            err.contains(expect),
            "case {i}: expected {expect:?} in {err}"
        );
    }
}
