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
        // Fewer environments than tasks would leave tasks untrained.
        ("tasks = \"mt10\"\nnum_envs = 2\n", "fewer than the run's 10 tasks"),
        // TERL's planner and guidance need the cluster's processes.
        (
            "tasks = \"reach-v3\"\nnum_envs = 1\nalgorithm = \"terl\"\n",
            "runs in a cluster only",
        ),
        // Sizes that would abort on allocation are refused when the run file is read.
        (
            "tasks = \"reach-v3\"\nnum_envs = 1\n[sac]\ncritic_hidden = [100000000]\n",
            "above 16384",
        ),
        (
            "tasks = \"reach-v3\"\nnum_envs = 1\n[sac]\npolicy_hidden = [16384, 16384]\n",
            "would not fit in memory",
        ),
        (
            "tasks = \"reach-v3\"\nnum_envs = 1\nalgorithm = \"care\"\n[sac.care]\ntemperature = 1e-300\n",
            "temperature",
        ),
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

/// `terl train --config FILE --out OUT` with extra arguments; the output.
fn train(config: &std::path::Path, out: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["train", "--config"])
        .arg(config)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn an_existing_folder_is_never_trained_into() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("other-run");
    std::fs::create_dir_all(out.join("checkpoints")).unwrap();
    std::fs::write(out.join("config.toml"), "tasks = \"push-v3\"\n").unwrap();
    let o = train(&root().join("deploy/configs/smoke.toml"), &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("already exists"), "{err}");
    assert_eq!(
        std::fs::read_to_string(out.join("config.toml")).unwrap(),
        "tasks = \"push-v3\"\n"
    );
    assert!(!out.join("progress.jsonl").exists());
    // An empty folder is fine (a folder made for the run beforehand).
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let o = train(
        &root().join("deploy/configs/smoke.toml"),
        &empty,
        &["--steps", "1200"],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `terl eval` of `checkpoint` with extra arguments (2 episodes per task, JSON); the output.
fn eval(checkpoint: &std::path::Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["eval", "--episodes-per-task", "2", "--json", "--checkpoint"])
        .arg(checkpoint)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn a_care_checkpoint_keeps_its_task_order_and_meets_new_tasks_through_their_embeddings() {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("care.toml");
    std::fs::write(
        &config,
        "tasks = \"reach-v3,push-v3\"\nalgorithm = \"care\"\nnum_envs = 2\neval_envs_per_task = 1\n\
         [train]\ntotal_env_steps = 1_500\nwarmup_env_steps = 1_000\neval_every_env_steps = 1_000\n\
         [sac]\npolicy_hidden = [16]\ncritic_hidden = [16]\nbatch_size = 32\nthreads = 1\n\
         [sac.care]\nnum_experts = 2\nexpert_hidden = [8]\nfeature_dim = 8\n\
         context_hidden = [8]\nencoding_dim = 8\ngate_hidden = [8]\n",
    )
    .unwrap();
    let out = dir.path().join("run");
    let o = train(&config, &out, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A lone copy of the checkpoint, away from its run folder's config.toml.
    let lone = dir.path().join("lone.safetensors");
    std::fs::copy(out.join("checkpoints/final.safetensors"), &lone).unwrap();
    let o = eval(&lone, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        v["trained_tasks"],
        serde_json::json!(["reach-v3", "push-v3"])
    );
    // The task order is recorded: a swapped order is refused.
    let o = eval(&lone, &["--trained-tasks", "push-v3,reach-v3"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("in this order"), "{err}");
    // A task it was not trained on gets its own description embedding, and says so.
    let o = eval(&lone, &["--tasks", "door-close-v3"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["unseen_task_encoding"], "task-embedding");
    assert_eq!(v["tasks"][0]["encoding"], "task-embedding");
    assert_eq!(v["tasks"][0]["trained"], false);
    let o = eval(
        &lone,
        &[
            "--tasks",
            "door-close-v3",
            "--unseen-task-encoding",
            "zeros",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(err.contains("does not apply to this CARE policy"), "{err}");
}
