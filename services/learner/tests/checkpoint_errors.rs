//! `[cluster] on_checkpoint_error` through the real learner: `terl_learner::run` on a real
//! gRPC listener (127.0.0.1, port 0) and the in-memory transport, fed transitions by a
//! stand-in actor, with its checkpoint folder replaced by a file mid-run (a write that fails
//! also as root).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use terl_transport::{MemoryBus, MemoryTransport};

mod common;

use common::feed;

const LIMIT: Duration = Duration::from_secs(120);

fn run_file(dir: &Path, on_error: &str) -> terl_runtime::RunConfig {
    let path = dir.join("run.toml");
    std::fs::write(
        &path,
        format!(
            "tasks = \"reach-v3,push-v3\"\nnum_envs = 2\n\
             [train]\nwarmup_env_steps = 256\nupdates_per_vec_step = 1.0\n\
             replay_capacity_per_task = 5_000\nseed = 1\n\
             [sac]\npolicy_hidden = [16, 16]\ncritic_hidden = [16, 16]\nbatch_size = 16\nthreads = 1\n\
             [cluster]\npublish_every_updates = 10\ncheckpoint_every_secs = 1\n\
             keep_checkpoints = 2\nblock_timeout_secs = 1\nbuffer_batches = 8\n\
             on_checkpoint_error = \"{on_error}\"\n"
        ),
    )
    .unwrap();
    terl_runtime::RunConfig::load(&path).unwrap()
}

fn unique(name: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("{name}-{}-{nanos}", std::process::id())
}

async fn status(addr: &str) -> Option<terl_wire::LearnerStatus> {
    let mut client = terl_wire::connect_learner(addr).await.ok()?;
    client.status().await.ok()
}

/// Waits for the trainer to write its first periodic checkpoint, then replaces the folder with a
/// file.
fn break_checkpoint_folder(dir: &Path) {
    let start = Instant::now();
    // After the first periodic checkpoint the learner has opened the folder and is training:
    // breaking it earlier fails the learner's start-up instead (a race on a loaded machine).
    let holds_a_checkpoint = || {
        std::fs::read_dir(dir).is_ok_and(|d| {
            d.filter_map(Result::ok).any(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                name.starts_with("update-") && name.ends_with(".safetensors")
            })
        })
    };
    loop {
        assert!(
            start.elapsed() < LIMIT,
            "{} never held a checkpoint",
            dir.display()
        );
        if holds_a_checkpoint() && std::fs::remove_dir_all(dir).is_ok() {
            std::fs::write(dir, "a file where the checkpoint folder was").unwrap();
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

struct Learner {
    rt: tokio::runtime::Runtime,
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    addr: String,
    stop: tokio::sync::watch::Sender<bool>,
    feeder_stop: Arc<AtomicBool>,
    feeder: std::thread::JoinHandle<u64>,
    run_dir: PathBuf,
}

fn start(dir: &Path, on_error: &str) -> Learner {
    let run = run_file(dir, on_error);
    let run_id = unique("ckpt-errors");
    let run_dir = dir.join("run");
    let transport_config = run.cluster.transport_config(run_id.as_str(), 1);
    let bus = MemoryBus::default();
    let learner_transport = MemoryTransport::on_bus(bus.clone(), transport_config.clone()).unwrap();
    let actor_transport = MemoryTransport::on_bus(bus, transport_config).unwrap();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let (task, addr) = rt.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let config = terl_learner::LearnerConfig::new(run, run_id, addr, 1, run_dir.clone());
        let mut rx = stop_rx;
        let shutdown = async move {
            let _ = rx.wait_for(|s| *s).await;
        };
        let task = tokio::spawn(terl_learner::run(
            config,
            listener,
            learner_transport,
            shutdown,
        ));
        (task, addr.to_string())
    });
    let feeder_stop = Arc::new(AtomicBool::new(false));
    let feeder = feed(actor_transport, Arc::clone(&feeder_stop));
    Learner {
        rt,
        task,
        addr,
        stop,
        feeder_stop,
        feeder,
        run_dir,
    }
}

/// Under "stop", a periodic checkpoint that cannot be written stops the learner with an error
/// that names the file and the setting.
#[test]
fn a_failed_checkpoint_stops_the_learner_under_stop() {
    let dir = tempfile::tempdir().unwrap();
    let Learner {
        rt,
        task,
        stop,
        feeder_stop,
        feeder,
        run_dir,
        ..
    } = start(dir.path(), "stop");
    break_checkpoint_folder(&run_dir.join("checkpoints"));
    let result = rt.block_on(async move {
        tokio::time::timeout(LIMIT, task)
            .await
            .expect("the learner kept running after a failed checkpoint")
            .unwrap()
    });
    feeder_stop.store(true, Ordering::Relaxed);
    feeder.join().unwrap();
    let e = format!(
        "{:#}",
        result.expect_err("the learner stopped without an error")
    );
    assert!(
        e.contains("stopping: a checkpoint could not be written")
            && e.contains("on_checkpoint_error")
            && e.contains("cannot write the checkpoint")
            && e.contains("update-"),
        "{e}"
    );
    drop(stop);
}

/// Under "continue", failed checkpoints are counted in the status and training goes on; once
/// the folder is back, the learner stops cleanly with its final checkpoint.
#[test]
fn a_failed_checkpoint_is_counted_and_training_goes_on_under_continue() {
    let dir = tempfile::tempdir().unwrap();
    let Learner {
        rt,
        task,
        addr,
        stop,
        feeder_stop,
        feeder,
        run_dir,
    } = start(dir.path(), "continue");
    let ckpt = run_dir.join("checkpoints");
    break_checkpoint_folder(&ckpt);
    let (failed_at, updates_then) = rt.block_on(async {
        let start = Instant::now();
        loop {
            assert!(start.elapsed() < LIMIT, "no checkpoint failure counted");
            assert!(!task.is_finished(), "the learner stopped");
            if let Some(s) = status(&addr).await {
                if s.checkpoint_failures >= 2 {
                    return (s.checkpoint_failures, s.updates);
                }
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    rt.block_on(async {
        let start = Instant::now();
        loop {
            assert!(
                start.elapsed() < LIMIT,
                "no updates after {failed_at} failed checkpoints (updates {updates_then})"
            );
            assert!(!task.is_finished(), "the learner stopped");
            if let Some(s) = status(&addr).await {
                if s.updates > updates_then && s.env_steps_total > 0 {
                    return;
                }
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    });
    std::fs::remove_file(&ckpt).unwrap();
    std::fs::create_dir(&ckpt).unwrap();
    stop.send(true).unwrap();
    let result = rt.block_on(async move { tokio::time::timeout(LIMIT, task).await.unwrap() });
    feeder_stop.store(true, Ordering::Relaxed);
    feeder.join().unwrap();
    result.unwrap().unwrap();
    assert!(ckpt.join("final.safetensors").exists());
}
