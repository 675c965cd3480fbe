//! The whole cluster in one process: learner, selector and two actors, each through its
//! library `run` on the in-memory transport (one shared bus), with real gRPC on 127.0.0.1
//! port 0, real MuJoCo environments and real files in a temporary run folder. The
//! process-level tests (cluster.rs) cover the binaries over shared memory.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

use std::time::{Duration, Instant};

use terl_transport::{MemoryBus, MemoryTransport};

/// How long the cluster may take to show weights flowing and training (a failure bound on a
/// busy machine, not a performance check).
const LIMIT: Duration = Duration::from_secs(240);

/// cluster-smoke.toml with a shorter warm-up, frequent versions and no in-run evaluation.
fn run_file(dir: &std::path::Path) -> terl_runtime::RunConfig {
    let path = dir.join("run.toml");
    std::fs::write(
        &path,
        "tasks = \"reach-v3,push-v3\"\nnum_envs = 2\neval_envs_per_task = 1\nvariation_seed = 0\n\
         [train]\nwarmup_env_steps = 500\nupdates_per_vec_step = 1.0\n\
         replay_capacity_per_task = 10_000\nsuccess_window = 10\nseed = 1\n\
         eval_every_env_steps = 0\n\
         [sac]\npolicy_hidden = [32, 32]\ncritic_hidden = [32, 32]\nbatch_size = 32\nthreads = 1\nseed = 1\n\
         [cluster]\nenvs_per_actor = 1\npublish_every_updates = 10\ncheckpoint_every_secs = 0\n\
         keep_checkpoints = 2\nblock_timeout_secs = 10\nbuffer_batches = 8\n\
         learner_calibrate_secs = 0.1\n",
    )
    .unwrap();
    terl_runtime::RunConfig::load(&path).unwrap()
}

#[test]
fn learner_selector_and_two_actors_train_in_one_process() {
    terl_runtime::init_tracing();
    let dir = tempfile::tempdir().unwrap();
    let run = run_file(dir.path());
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    let run_id = format!("in-process-{}-{nanos}", std::process::id());
    let run_dir = dir.path().join("run");
    let bus = MemoryBus::default();
    let transport = || {
        MemoryTransport::on_bus(
            bus.clone(),
            run.cluster.transport_config(run_id.as_str(), 2),
        )
        .unwrap()
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let (stop, stop_rx) = tokio::sync::watch::channel(false);
    let shutdown = || {
        let mut rx = stop_rx.clone();
        async move {
            let _ = rx.wait_for(|s| *s).await;
        }
    };

    rt.block_on(async {
        let learner_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let selector_listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let learner_addr = learner_listener.local_addr().unwrap();
        let selector_addr = selector_listener.local_addr().unwrap();

        let config = terl_learner::LearnerConfig::new(
            run.clone(),
            run_id.clone(),
            learner_addr,
            2,
            run_dir.clone(),
        );
        let learner = tokio::spawn(terl_learner::run(
            config,
            learner_listener,
            transport(),
            shutdown(),
        ));
        let mut config = terl_selector::SelectorConfig::new(
            run.clone(),
            run_id.clone(),
            selector_addr,
            2,
            run_dir.clone(),
        );
        config.learner_addr = Some(learner_addr.to_string());
        let selector = tokio::spawn(terl_selector::run(
            config,
            selector_listener,
            transport(),
            shutdown(),
        ));
        let actors: Vec<_> = (0..2)
            .map(|id| {
                let config = terl_actor::ActorConfig::new(
                    run.clone(),
                    run_id.clone(),
                    id,
                    2,
                    learner_addr.to_string(),
                );
                tokio::spawn(terl_actor::run(config, transport(), shutdown()))
            })
            .collect();

        let start = Instant::now();
        let (learner_status, selector_status) = loop {
            assert!(
                start.elapsed() < LIMIT,
                "within {LIMIT:?} the cluster did not train with both actors on published weights"
            );
            for (what, task) in [("learner", &learner), ("selector", &selector)] {
                assert!(!task.is_finished(), "the {what} stopped");
            }
            for a in &actors {
                assert!(!a.is_finished(), "an actor stopped");
            }
            tokio::time::sleep(Duration::from_millis(250)).await;
            let Ok(mut l) = terl_wire::connect_learner(&learner_addr.to_string()).await else {
                continue;
            };
            let Ok(mut s) = terl_wire::connect_selector(&selector_addr.to_string()).await else {
                continue;
            };
            let (Ok(ls), Ok(ss)) = (l.status().await, s.status().await) else {
                continue;
            };
            let actors_on_weights = ls.actors.len() == 2
                && ls
                    .actors
                    .iter()
                    .all(|a| a.policy_version > 0 && a.env_steps > 0);
            if ls.updates > 0 && ls.policy_version > 0 && actors_on_weights && ss.episodes_seen > 0
            {
                break (ls, ss);
            }
        };
        // Both services announced their addresses in the run folder.
        for (service, addr) in [("learner", learner_addr), ("selector", selector_addr)] {
            let text = std::fs::read_to_string(run_dir.join(format!("{service}.addr"))).unwrap();
            assert_eq!(text.trim(), addr.to_string());
        }
        assert_eq!(learner_status.run_id, run_id);
        assert_eq!(selector_status.run_id, run_id);
        assert!(learner_status.env_steps_total >= 500, "{learner_status:?}");
        assert_eq!(learner_status.rejected_batches, 0);
        // The learner timed its standalone rate before training.
        assert!(
            learner_status.standalone_updates_per_second > 0.0,
            "{learner_status:?}"
        );
        let mut ids: Vec<u32> = learner_status.actors.iter().map(|a| a.actor_id).collect();
        ids.sort_unstable();
        assert_eq!(ids, [0, 1]);

        stop.send(true).unwrap();
        for (what, task) in [("learner", learner), ("selector", selector)] {
            tokio::time::timeout(LIMIT, task)
                .await
                .unwrap_or_else(|_| panic!("the {what} did not stop"))
                .unwrap()
                .unwrap_or_else(|e| panic!("the {what} failed: {e:#}"));
        }
        for a in actors {
            tokio::time::timeout(LIMIT, a)
                .await
                .expect("an actor did not stop")
                .unwrap()
                .unwrap_or_else(|e| panic!("an actor failed: {e:#}"));
        }
    });
    // The learner's final checkpoint and the selector's episode log are in the run folder.
    assert!(run_dir.join("checkpoints/final.safetensors").exists());
    assert!(run_dir.join("episodes.mcap").exists());
}
