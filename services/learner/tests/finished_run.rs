//! A finished run stays finished: `terl_learner::run` on a real gRPC listener (127.0.0.1, port
//! 0) and the in-memory transport, fed by a stand-in actor until its env-step budget is reached;
//! then started again with `--resume` as a supervisor would (a Kubernetes Deployment restarts a
//! container that exits, even with code 0). Resumed, it writes no file and exits at once, or with
//! `--when-finished idle` keeps answering status; a fresh run with `idle` keeps serving after it
//! reaches its budget.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use terl_transport::{MemoryBus, MemoryTransport};

mod common;

use common::feed;

const LIMIT: Duration = Duration::from_secs(120);
const BUDGET: u64 = 2_048;

fn run_file(dir: &Path) -> terl_runtime::RunConfig {
    let path = dir.join("run.toml");
    std::fs::write(
        &path,
        format!(
            "tasks = \"reach-v3,push-v3\"\nnum_envs = 2\n\
             [train]\ntotal_env_steps = {BUDGET}\nwarmup_env_steps = 256\n\
             updates_per_vec_step = 1.0\nreplay_capacity_per_task = 5_000\nseed = 1\n\
             [sac]\npolicy_hidden = [16, 16]\ncritic_hidden = [16, 16]\nbatch_size = 16\n\
             threads = 1\n\
             [cluster]\npublish_every_updates = 10\ncheckpoint_every_secs = 1\n\
             block_timeout_secs = 1\nbuffer_batches = 8\n"
        ),
    )
    .unwrap();
    terl_runtime::RunConfig::load(&path).unwrap()
}

/// Every file under `dir` with its length and modification time.
fn files(dir: &Path) -> BTreeMap<PathBuf, (u64, SystemTime)> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let m = e.metadata().unwrap();
            if m.is_dir() {
                stack.push(e.path());
            } else {
                out.insert(e.path(), (m.len(), m.modified().unwrap()));
            }
        }
    }
    out
}

async fn status(addr: &str) -> Option<terl_wire::LearnerStatus> {
    let mut client = terl_wire::connect_learner(addr).await.ok()?;
    client.status().await.ok()
}

struct Learner {
    task: tokio::task::JoinHandle<anyhow::Result<()>>,
    addr: String,
    stop: tokio::sync::watch::Sender<bool>,
    feeder_stop: Arc<AtomicBool>,
    feeder: std::thread::JoinHandle<u64>,
}

/// Starts a learner of the run in `dir` (with a stand-in actor feeding it) on `rt`.
fn start(rt: &tokio::runtime::Runtime, dir: &Path, resume: bool, idle: bool) -> Learner {
    let run = run_file(dir);
    let run_id = format!("finished-{}-{}", std::process::id(), u8::from(resume));
    let transport_config = run.cluster.transport_config(run_id.as_str(), 1);
    let bus = MemoryBus::default();
    let learner_transport = MemoryTransport::on_bus(bus.clone(), transport_config.clone()).unwrap();
    let actor_transport = MemoryTransport::on_bus(bus, transport_config).unwrap();
    let (stop, mut stop_rx) = tokio::sync::watch::channel(false);
    let (task, addr) = rt.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let mut config = terl_learner::LearnerConfig::new(run, run_id, addr, 1, dir.join("run"));
        config.resume = resume;
        config.idle_when_finished = idle;
        let shutdown = async move {
            let _ = stop_rx.wait_for(|s| *s).await;
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
        task,
        addr,
        stop,
        feeder_stop,
        feeder,
    }
}

impl Learner {
    /// Waits for the learner to end by itself (its budget) and returns its outcome.
    fn finishes(self, rt: &tokio::runtime::Runtime, what: &str) -> anyhow::Result<()> {
        let result = rt.block_on(async {
            tokio::time::timeout(LIMIT, self.task)
                .await
                .unwrap_or_else(|_| panic!("{what}: the learner did not end by itself"))
                .unwrap()
        });
        self.feeder_stop.store(true, Ordering::Relaxed);
        self.feeder.join().unwrap();
        drop(self.stop);
        result
    }

    /// Waits for a status that satisfies `ok`, checking the learner still runs.
    fn status_until(
        &self,
        rt: &tokio::runtime::Runtime,
        what: &str,
        ok: impl Fn(&terl_wire::LearnerStatus) -> bool,
    ) -> terl_wire::LearnerStatus {
        rt.block_on(async {
            let start = Instant::now();
            loop {
                assert!(start.elapsed() < LIMIT, "{what}: no such status");
                assert!(!self.task.is_finished(), "{what}: the learner ended");
                if let Some(s) = status(&self.addr).await {
                    if ok(&s) {
                        return s;
                    }
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        })
    }

    /// Stops the learner (SIGTERM's path) and returns its outcome.
    fn stop(self, rt: &tokio::runtime::Runtime) -> anyhow::Result<()> {
        self.stop.send(true).unwrap();
        let result = rt.block_on(async {
            tokio::time::timeout(LIMIT, self.task)
                .await
                .expect("the learner did not stop")
                .unwrap()
        });
        self.feeder_stop.store(true, Ordering::Relaxed);
        self.feeder.join().unwrap();
        result
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

/// A run trained to its budget, then resumed twice: without `idle` the learner exits 0 at once
/// and every file of the run stays as it was (no new metrics log, final checkpoint untouched);
/// with `idle` it answers status with the finished run's counters, writes nothing but its
/// address file, and stops cleanly when told to.
#[test]
fn a_resumed_finished_run_writes_nothing_and_exits_or_idles() {
    let rt = runtime();
    let dir = tempfile::tempdir().unwrap();
    start(&rt, dir.path(), false, false)
        .finishes(&rt, "the first run")
        .unwrap();
    let run_dir = dir.path().join("run");
    let before = files(&run_dir);
    assert!(
        before
            .keys()
            .any(|p| p.ends_with("checkpoints/final.safetensors")),
        "{before:?}"
    );

    let started = Instant::now();
    start(&rt, dir.path(), true, false)
        .finishes(&rt, "a resumed finished run")
        .unwrap();
    assert!(
        started.elapsed() < Duration::from_secs(30),
        "the finished run's learner took {:?} to exit",
        started.elapsed()
    );
    assert_eq!(
        files(&run_dir),
        before,
        "a resumed finished run wrote files"
    );

    let idle = start(&rt, dir.path(), true, true);
    let s = idle.status_until(&rt, "the idle learner", |s| s.env_steps_total > 0);
    assert!(s.env_steps_total >= BUDGET, "{s:?}");
    assert!(s.updates > 0, "{s:?}");
    // Still serving a while later, with nothing trained.
    std::thread::sleep(Duration::from_secs(2));
    let later = idle.status_until(&rt, "the idle learner", |_| true);
    assert_eq!(
        (later.updates, later.env_steps_total),
        (s.updates, s.env_steps_total)
    );
    idle.stop(&rt).unwrap();
    let mut after = files(&run_dir);
    after.retain(|p, _| !p.ends_with("learner.addr"));
    let mut expected = before.clone();
    expected.retain(|p, _| !p.ends_with("learner.addr"));
    assert_eq!(after, expected, "an idle finished learner wrote files");
}

/// With `idle`, a run that reaches its budget writes its final checkpoint and keeps answering
/// status (the budget reached, updates no longer moving) instead of exiting.
#[test]
fn an_idle_learner_keeps_serving_after_its_budget() {
    let rt = runtime();
    let dir = tempfile::tempdir().unwrap();
    let learner = start(&rt, dir.path(), false, true);
    let final_checkpoint = dir.path().join("run/checkpoints/final.safetensors");
    let start = Instant::now();
    while !final_checkpoint.exists() {
        assert!(start.elapsed() < LIMIT, "no final checkpoint");
        assert!(!learner.task.is_finished(), "the learner ended");
        std::thread::sleep(Duration::from_millis(50));
    }
    let s = learner.status_until(&rt, "after the budget", |s| s.env_steps_total >= BUDGET);
    std::thread::sleep(Duration::from_secs(1));
    let later = learner.status_until(&rt, "after the budget", |_| true);
    assert_eq!(later.updates, s.updates, "it kept training");
    learner.stop(&rt).unwrap();
}
