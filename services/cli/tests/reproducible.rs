//! Reproducible cluster runs (`[cluster] reproducible = true`) end to end: the launcher runs a
//! learner, a selector and two actors as real processes over iceoryx2 and gRPC on
//! `deploy/configs/cluster-smoke.toml` with a training budget, three times. Two runs with the same
//! seed — the second with every core kept busy by spinning threads, so the processes' timing
//! differs — end with byte-identical final checkpoints (networks, optimiser state, sampler state,
//! counters, success windows); a run with another seed ends with a different one.

use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

mod common;

use common::{service_binaries, workspace};

/// Runs the launcher on `config` to its budget and returns the final checkpoint's bytes.
fn run_to_budget(root: &Path, config: &Path, run_id: &str) -> Vec<u8> {
    let runs = tempfile::tempdir().unwrap();
    let start = Instant::now();
    let mut child = Command::new(root.join("deploy/local-cluster.sh"))
        .current_dir(root)
        .args(["--config", config.to_str().unwrap(), "--actors", "2"])
        .args(["--run-id", run_id, "--no-build"])
        .args(["--runs-root", runs.path().to_str().unwrap()])
        .args([
            "--learner-addr",
            "127.0.0.1:0",
            "--selector-addr",
            "127.0.0.1:0",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(300) {
            let _ = Command::new("kill")
                .args(["-INT", &child.id().to_string()])
                .status();
            panic!("the reproducible cluster did not stop at its budget");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    let run_dir = runs.path().join(run_id);
    let logs: String = ["learner.log", "actor-0.log", "actor-1.log"]
        .iter()
        .map(|f| std::fs::read_to_string(run_dir.join(f)).unwrap_or_default())
        .collect();
    assert!(
        status.success(),
        "launcher exited with {status}: {err}\n{logs}"
    );
    std::fs::read(run_dir.join("checkpoints/final.safetensors"))
        .unwrap_or_else(|e| panic!("no final checkpoint ({e}): {err}\n{logs}"))
}

/// The learner state JSON of a checkpoint (its safetensors header's metadata).
fn learner_state(checkpoint: &[u8]) -> serde_json::Value {
    let n = u64::from_le_bytes(checkpoint[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&checkpoint[8..8 + n]).unwrap();
    let state = header["__metadata__"]["terl.learner_state"]
        .as_str()
        .unwrap();
    serde_json::from_str(state).unwrap()
}

#[test]
fn same_seed_clusters_end_with_identical_checkpoints_and_another_seed_differs() {
    service_binaries();
    let root = workspace();
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root.join("deploy/configs/cluster-smoke.toml")).unwrap();
    for key in ["warmup_env_steps = 1_000", "seed = 1\n", "[cluster]\n"] {
        assert!(text.contains(key), "cluster-smoke.toml lost {key:?}");
    }
    let config = |seed: u64| {
        let path = dir.path().join(format!("seed-{seed}.toml"));
        let text = text
            .replace(
                "warmup_env_steps = 1_000",
                "total_env_steps = 6_400\nwarmup_env_steps = 1_000",
            )
            .replace("seed = 1\n", &format!("seed = {seed}\n"))
            .replace("[cluster]\n", "[cluster]\nreproducible = true\n")
            // Two learner threads: the parallel GEMM must be deterministic too.
            .replace("threads = 1", "threads = 2");
        std::fs::write(&path, text).unwrap();
        path
    };
    let pid = std::process::id();
    let first = run_to_budget(&root, &config(1), &format!("it-repro-a-{pid}"));

    // The second run with every core busy.
    let stop = Arc::new(AtomicBool::new(false));
    let spinners: Vec<_> = (0..std::thread::available_parallelism().map_or(2, |n| n.get()))
        .map(|_| {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                let mut x = 1u64;
                while !stop.load(Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect();
    let second = run_to_budget(&root, &config(1), &format!("it-repro-b-{pid}"));
    stop.store(true, Ordering::Relaxed);
    spinners.into_iter().for_each(|s| s.join().unwrap());
    let other = run_to_budget(&root, &config(2), &format!("it-repro-c-{pid}"));

    // The runs trained: the budget was received, the policy was published and acted.
    let state = learner_state(&first);
    assert!(state["env_steps"].as_u64().unwrap() >= 6_400, "{state}");
    assert!(state["policy_version"].as_u64().unwrap() > 0, "{state}");
    assert_eq!(
        learner_state(&second),
        state,
        "the learner state of two same-seed runs differs"
    );
    assert!(
        first == second,
        "same-seed reproducible runs ended with different checkpoints ({} and {} bytes)",
        first.len(),
        second.len()
    );
    assert_eq!(first.len(), other.len(), "the same networks");
    assert!(first != other, "another seed gave the same checkpoint");
}
