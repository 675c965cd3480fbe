//! The cluster end to end: learner, selector and two actors as real processes on
//! `deploy/configs/cluster-smoke.toml`, servers on port 0, a unique run id. Checks that
//! transitions flow (env steps grow), actors act with new policy versions, status is
//! consistent (success windows fill), checkpoints appear, and SIGTERM shuts everything down
//! cleanly (exit 0, no shared-memory files left behind).
//!
//! The TERL test runs the same processes on `deploy/configs/smoke-terl.toml` and checks the
//! paper's loop: the selector scores episodes and selects samples, the learner trains the
//! planner on them (F's predicted goal distance grows from one step towards the data's, its targets stay ≥ 1) and publishes it, actors take guided actions, the MCAP
//! dataset holds the selected samples, and a new learner can start from that dataset.
//!
//! The MT50 test runs `deploy/configs/mt50-smoke.toml` and checks that episodes of all 50
//! tasks reach the learner and the selector.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

const TIMEOUT: Duration = Duration::from_secs(60);

mod common;

use common::{service_binaries, workspace};

/// iceoryx2's files in `/dev/shm`, except its per-version global management file
/// (`iox2_<hash>_node.<version>.global_mgmt`): the first node on a machine creates it and it
/// stays by design, so it is not a leftover of any run.
fn shm_files() -> BTreeSet<String> {
    std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with("iox2_") && !n.ends_with(".global_mgmt"))
                .collect()
        })
        .unwrap_or_default()
}

struct Cluster {
    children: Vec<(String, Child)>,
}

impl Drop for Cluster {
    fn drop(&mut self) {
        for (_, child) in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

impl Cluster {
    fn spawn(&mut self, name: &str, bin: &Path, args: &[String], log_dir: &Path) {
        let log = std::fs::File::create(log_dir.join(format!("{name}.log"))).unwrap();
        let child = Command::new(bin)
            .args(args)
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()));
        self.children.push((name.to_string(), child));
    }
}

fn wait_for_file(path: &Path) -> String {
    common::wait_for_addr(path, None, TIMEOUT)
}

fn status(learner: &str, selector: &str) -> Option<Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args([
            "status",
            "--json",
            "--addr",
            learner,
            "--selector-addr",
            selector,
        ])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    serde_json::from_slice(&out.stdout).ok()
}

fn u(v: &Value, path: &[&str]) -> u64 {
    let mut v = v;
    for p in path {
        v = &v[p];
    }
    v.as_u64().unwrap_or(0)
}

/// A running cluster of real processes with its run folder.
struct Running {
    cluster: Cluster,
    run_id: String,
    run_dir: PathBuf,
    learner: String,
    selector: String,
    _dir: tempfile::TempDir,
}

/// Starts learner, selector (following the learner) and two actors on `config`.
fn start(config: &str, learner_extra: &[&str]) -> Running {
    let bins = service_binaries();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    let run_id = format!("it-{}-{nanos}", std::process::id());
    let dir = tempfile::tempdir().unwrap();
    let run_dir = dir.path().join(&run_id);
    std::fs::create_dir_all(&run_dir).unwrap();
    let config = workspace().join(config);
    let common = |extra: &[&str]| -> Vec<String> {
        let mut v = vec![
            "--config".to_string(),
            config.display().to_string(),
            "--run-id".into(),
            run_id.clone(),
            "--num-actors".into(),
            "2".into(),
        ];
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run_dir_s = run_dir.display().to_string();
    let mut cluster = Cluster { children: vec![] };
    let mut learner_args = vec!["--addr", "127.0.0.1:0", "--run-dir", &run_dir_s];
    learner_args.extend_from_slice(learner_extra);
    cluster.spawn(
        "learner",
        &bins.join("terl-learner"),
        &common(&learner_args),
        &run_dir,
    );
    let learner = wait_for_file(&run_dir.join("learner.addr"));
    cluster.spawn(
        "selector",
        &bins.join("terl-selector"),
        &common(&[
            "--addr",
            "127.0.0.1:0",
            "--run-dir",
            &run_dir_s,
            "--learner-addr",
            &learner,
        ]),
        &run_dir,
    );
    let selector = wait_for_file(&run_dir.join("selector.addr"));
    for id in ["0", "1"] {
        cluster.spawn(
            &format!("actor{id}"),
            &bins.join("terl-actor"),
            &common(&["--actor-id", id, "--learner-addr", &learner]),
            &run_dir,
        );
    }
    Running {
        cluster,
        run_id,
        run_dir,
        learner,
        selector,
        _dir: dir,
    }
}

/// SIGTERMs every process at once, as the launcher does; everyone must exit 0, promptly.
fn stop_all(cluster: &mut Cluster, run_dir: &Path) {
    for (_, child) in &cluster.children {
        let ok = Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok);
    }
    let stop = Instant::now();
    for (name, child) in &mut cluster.children {
        let status = loop {
            if let Some(status) = child.try_wait().unwrap() {
                break status;
            }
            assert!(
                stop.elapsed() < Duration::from_secs(30),
                "{name} did not stop after SIGTERM"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        assert!(
            status.success(),
            "{name} exited with {status}; log {}",
            run_dir.join(format!("{name}.log")).display()
        );
    }
    eprintln!("all processes stopped {:?} after SIGTERM", stop.elapsed());
}

// One end-to-end scenario whose steps share the running cluster; split would repeat the set-up.
#[allow(clippy::too_many_lines)]
#[test]
fn cluster_trains_and_shuts_down_cleanly() {
    let shm_before = shm_files();
    let Running {
        mut cluster,
        run_id,
        run_dir,
        learner,
        selector,
        _dir,
    } = start("deploy/configs/cluster-smoke.toml", &[]);

    // Poll until every property held at least once, remembering what grew.
    let start = Instant::now();
    let mut first: Option<Value> = None;
    let mut versions_seen: BTreeSet<u64> = BTreeSet::new();
    let (mut steps_grew, mut versions_advanced, mut windows_filled) = (false, false, false);
    let mut evaluated = false;
    let mut last = Value::Null;
    while !(steps_grew && versions_advanced && windows_filled && evaluated) {
        assert!(
            start.elapsed() < TIMEOUT,
            "cluster did not make progress in {TIMEOUT:?}; last status {last}; logs in {}",
            run_dir.display()
        );
        std::thread::sleep(Duration::from_millis(1000));
        let Some(s) = status(&learner, &selector) else {
            continue;
        };
        let l = &s["learner"];
        assert_eq!(l["run_id"], Value::String(run_id.clone()));
        assert!(u(l, &["replay_size"]) <= u(l, &["replay_capacity"]));
        let actors = l["actors"].as_array().cloned().unwrap_or_default();
        for a in &actors {
            let v = u(a, &["policy_version"]);
            assert!(
                v <= u(l, &["policy_version"]),
                "actor ahead of learner: {s}"
            );
            if v > 0 {
                versions_seen.insert(v);
            }
        }
        let actor_versions: Vec<u64> = actors.iter().map(|a| u(a, &["policy_version"])).collect();
        if let Some(f) = &first {
            steps_grew |= u(l, &["env_steps_total"]) > u(&f["learner"], &["env_steps_total"])
                && actors.len() == 2
                && actors.iter().all(|a| u(a, &["env_steps"]) > 0);
        } else if u(l, &["env_steps_total"]) > 0 {
            first = Some(s.clone());
        }
        versions_advanced = versions_seen.len() >= 2
            && actor_versions.len() == 2
            && actor_versions.iter().all(|&v| v > 0);
        let sel = &s["selector"];
        let sel_tasks = sel["task_success"].as_array().cloned().unwrap_or_default();
        windows_filled = u(sel, &["episodes_seen"]) > 0
            && sel_tasks.len() == 2
            && sel_tasks.iter().all(|t| u(t, &["episodes"]) > 0)
            && l["task_success"]
                .as_array()
                .is_some_and(|ts| ts.iter().all(|t| u(t, &["episodes"]) > 0));
        // The selector's evaluator: the latest policy, deterministic, on both tasks, every
        // 2000 env steps (cluster-smoke.toml), 2 episodes per task.
        let e = &sel["last_eval"];
        if e.is_object() {
            assert!(u(e, &["env_steps"]) >= 2_000, "{e}");
            assert!(
                u(e, &["policy_version"]) <= u(l, &["policy_version"]),
                "{e}"
            );
            assert_eq!(u(e, &["episodes_per_task"]), 2);
            let names: Vec<&str> = e["tasks"]
                .as_array()
                .unwrap()
                .iter()
                .map(|t| t["task"].as_str().unwrap())
                .collect();
            assert_eq!(names, ["reach-v3", "push-v3"]);
            evaluated = u(e, &["policy_version"]) > 0;
        }
        last = s;
    }
    eprintln!("status after {:?}: {last}", start.elapsed());
    eprintln!("policy versions actors acted with: {versions_seen:?}");

    let checkpoints = run_dir.join("checkpoints");
    let periodic = || {
        std::fs::read_dir(&checkpoints)
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .filter(|e| e.file_name().to_string_lossy().starts_with("update-"))
                    .count()
            })
            .unwrap_or(0)
    };
    while periodic() == 0 {
        assert!(start.elapsed() < TIMEOUT, "no periodic checkpoint");
        std::thread::sleep(Duration::from_millis(200));
    }

    let episodes_seen = u(&last["selector"], &["episodes_seen"]);
    let evaluations = u(&last["selector"], &["evaluations"]);
    let table = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["status", "--addr", &learner, "--selector-addr", &selector])
        .output()
        .unwrap();
    let table = String::from_utf8_lossy(&table.stdout);
    assert!(
        table.contains("train success (stochastic policy, last")
            && table.contains("eval success (deterministic policy, 2 episodes/task) at env steps"),
        "{table}"
    );
    stop_all(&mut cluster, &run_dir);
    assert!(checkpoints.join("final.safetensors").is_file());

    // The learner's metrics and the selector's episode log are complete MCAP files.
    let metrics = terl_telemetry::read_log::<terl_wire::Metric>(run_dir.join("metrics.mcap"))
        .expect("metrics log readable");
    assert!(!metrics.truncated && metrics.rejected == 0);
    for name in [
        "losses/qf_loss",
        "charts/updates_per_second",
        "success_rate/push-v3",
    ] {
        assert!(
            metrics.records.iter().any(|m| m.name == name),
            "no {name} in the metrics log"
        );
    }
    assert!(
        !metrics.records.iter().any(|m| m.name.starts_with("tep/")),
        "an mtsac run logs no TEP metrics"
    );
    // `terl eval` reads the cluster's checkpoints: the run folder's newest is the final one.
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["eval", "--checkpoint", run_dir.to_str().unwrap()])
        .args([
            "--trained-tasks",
            "reach-v3,push-v3",
            "--episodes-per-task",
            "1",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let ev: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        ev["checkpoint"]
            .as_str()
            .unwrap()
            .ends_with("final.safetensors"),
        "{ev}"
    );
    assert!(
        u(&ev, &["policy_version"]) >= u(&last["learner"], &["policy_version"]),
        "{ev}"
    );
    assert_eq!(ev["tasks"].as_array().unwrap().len(), 2);

    // Every evaluation the status counted is in the selector's evaluation log, in order.
    let evals = terl_telemetry::read_log::<terl_wire::EvalResult>(run_dir.join("eval.mcap"))
        .expect("evaluation log readable");
    assert!(!evals.truncated && evals.rejected == 0);
    assert!(evals.records.len() as u64 >= evaluations.max(1));
    assert!(evals
        .records
        .windows(2)
        .all(|w| w[0].env_steps < w[1].env_steps && w[0].policy_version <= w[1].policy_version));
    let metric_names: Vec<String> = evals.records[0]
        .metrics()
        .into_iter()
        .map(|m| m.0)
        .collect();
    for name in [
        "eval/mean_success_rate",
        "eval/success_rate/reach-v3",
        "eval/return/push-v3",
        "eval/env_steps",
    ] {
        assert!(metric_names.iter().any(|n| n == name), "{metric_names:?}");
    }
    let episodes =
        terl_telemetry::read_log::<terl_wire::EpisodeSummary>(run_dir.join("episodes.mcap"))
            .expect("episode log readable");
    assert!(!episodes.truncated);
    assert!(episodes.records.len() as u64 >= episodes_seen);
    assert!(episodes
        .records
        .iter()
        .all(|e| e.length == 500 && e.guided_steps == 0));

    // The run's report: one table row per task with the logged episode counts, and a chart.
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["report", run_dir.to_str().unwrap(), "--window", "10"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(run_dir.join("report.md")).unwrap();
    for task in ["reach-v3", "push-v3"] {
        let n = episodes.records.iter().filter(|e| e.task == task).count();
        assert!(md.contains(&format!("| {task} | {n} | ")), "{task}: {md}");
    }
    assert!(md.contains("losses/qf_loss"), "{md}");
    assert!(
        md.contains("## In-run evaluation") && md.contains("| reach-v3 | push-v3 |"),
        "{md}"
    );
    let chart = std::fs::read_to_string(run_dir.join("learning-curves.svg")).unwrap();
    assert_eq!(chart.matches("<polyline").count(), 2);

    let leftover: Vec<String> = shm_files().difference(&shm_before).cloned().collect();
    assert!(
        leftover.is_empty(),
        "shared-memory files left: {leftover:?}"
    );
}

#[test]
fn terl_cluster_selects_trains_the_planner_and_guides() {
    let shm_before = shm_files();
    let mut run = start("deploy/configs/smoke-terl.toml", &[]);
    let start_time = Instant::now();
    let timeout = Duration::from_secs(150);
    // The planner check ran on both tasks' held-out selected trajectories and opened the gate
    // (the smoke config's min_spearman = -1): guidance then acts. That F learns to count steps
    // is checked offline (crates/rl tests/tep_distance.rs, tests/planner_cli.rs,
    // docs/results/planner/): on two minutes of a near-random policy's selected data the held-out
    // ρ is not a stable signal (measured 0.06..0.47 on reach, −0.46..0.47 on push).
    let mut rho_seen = false;
    let mut decisions_seen = false;
    let mut last = Value::Null;
    loop {
        assert!(
            start_time.elapsed() < timeout,
            "TERL loop incomplete after {timeout:?}; last status {last}; logs in {}",
            run.run_dir.display()
        );
        std::thread::sleep(Duration::from_millis(1000));
        let Some(s) = status(&run.learner, &run.selector) else {
            continue;
        };
        let (l, sel) = (&s["learner"], &s["selector"]);
        assert_eq!(l["algorithm"], "terl", "status: {s}");
        assert!(u(l, &["tep_buffer_size"]) <= u(l, &["tep_buffer_capacity"]));
        let loss = l["tep_f_loss"].as_f64().unwrap_or(0.0);
        if loss > 0.0 {
            // F ≥ 0 by construction; its targets (the hindsight gaps) are ≥ 2 steps.
            let target = l["tep_target_mean"].as_f64().unwrap_or(0.0);
            assert!(target >= 1.0, "mean TEP target {target} below 1: {s}");
            assert!(l["tep_goal_distance_mean"].as_f64().unwrap_or(-1.0) >= 0.0);
        }
        rho_seen |= l["planner"]["tasks"].as_array().is_some_and(|ts| {
            ts.len() == 2
                && ts.iter().all(|t| {
                    t["spearman"]
                        .as_f64()
                        .is_some_and(|r| (-1.0..=1.0).contains(&r))
                        && t["validated"] == true
                        && t["held_out_trajectories"].as_u64().unwrap_or(0) > 0
                })
        });
        let guided_rate_seen = l["task_success"].as_array().is_some_and(|ts| {
            ts.iter()
                .any(|t| t["guidance_rate"].as_f64().unwrap_or(0.0) > 0.0)
        });
        // The decision metrics of Eq. 15, as the actors measured them: σ^N where the planner may
        // act, the share of compared steps with f_t ≥ f_{t−1}, and ‖AN − π‖ of guided steps.
        for t in l["task_success"].as_array().into_iter().flatten() {
            if let Some(p) = t["guidance_probability"].as_f64() {
                assert!(p > 0.0 && p <= 1.0, "σ^N {p}: {s}");
            }
            if let Some(r) = t["not_improving_rate"].as_f64() {
                assert!(
                    (0.0..=1.0).contains(&r) && u(t, &["compared_steps"]) > 0,
                    "{s}"
                );
            }
            if let Some(g) = t["action_gap"].as_f64() {
                assert!((0.0..=4.0).contains(&g), "‖AN − π‖ {g}: {s}");
                assert!(t["guidance_rate"].as_f64().unwrap_or(0.0) > 0.0, "{s}");
            }
        }
        decisions_seen |= l["task_success"].as_array().is_some_and(|ts| {
            ts.iter().any(|t| {
                t["guidance_probability"].as_f64().is_some()
                    && t["not_improving_rate"].as_f64().is_some()
                    && t["action_gap"].as_f64().is_some_and(|g| g > 0.0)
            })
        });
        let done = u(sel, &["selected_samples"]) > 0
            && u(sel, &["priority", "scored"]) > 0
            && u(sel, &["critic_version"]) > 0
            && u(l, &["selected_samples"]) > 0
            && u(l, &["tep_updates"]) >= 20
            && u(l, &["planner_version"]) > 0
            && u(l, &["guided_steps"]) > 0
            && guided_rate_seen
            && decisions_seen
            && rho_seen;
        last = s;
        if done {
            break;
        }
    }
    eprintln!("status after {:?}: {last}", start_time.elapsed());
    let sel_selected = u(&last["selector"], &["selected_samples"]);
    stop_all(&mut run.cluster, &run.run_dir);

    // Every selected sample is in the dataset (flushed per batch, closed on shutdown); the
    // learner's planner checkpoint exists.
    let dataset = run.run_dir.join("tep-dataset.mcap");
    let data = terl_telemetry::read_tep_dataset(&dataset).expect("dataset readable");
    assert!(!data.truncated, "the selector closed the dataset cleanly");
    assert_eq!(data.rejected, 0);
    assert!(data.samples.len() as u64 >= sel_selected);
    assert!(data
        .samples
        .iter()
        .all(|x| ["reach-v3", "push-v3"].contains(&x.task.as_str())));
    assert!(run
        .run_dir
        .join("checkpoints/planner.safetensors")
        .is_file());
    let metrics = terl_telemetry::read_log::<terl_wire::Metric>(run.run_dir.join("metrics.mcap"))
        .expect("metrics log readable");
    let logged = |name: &str| metrics.records.iter().filter(|m| m.name == name).count();
    assert!(logged("tep/f_loss") > 0 && logged("guidance/rate/reach-v3") > 0);
    assert!(logged("tep/target_mean") > 0 && logged("tep/goal_distance_mean") > 0);
    for name in [
        "guidance/probability/",
        "guidance/not_improving_rate/",
        "guidance/action_gap/",
    ] {
        assert!(
            metrics.records.iter().any(|m| m.name.starts_with(name)),
            "{name}* in metrics.mcap"
        );
    }
    assert!(metrics
        .records
        .iter()
        .filter(|m| m.name == "tep/target_mean" && m.value != 0.0)
        .all(|m| m.value >= 1.0));
    assert!(metrics
        .records
        .iter()
        .any(|m| m.name.starts_with("guidance/rate/") && m.value > 0.0));
    let episodes =
        terl_telemetry::read_log::<terl_wire::EpisodeSummary>(run.run_dir.join("episodes.mcap"))
            .expect("episode log readable");
    assert!(
        episodes.records.iter().any(|e| e.guided_steps > 0),
        "guided steps are counted per episode"
    );

    // A new learner starts its TEP buffer from that dataset.
    let bins = service_binaries();
    let run_id = format!("{}-reload", run.run_id);
    let run_dir = run.run_dir.with_file_name(&run_id);
    std::fs::create_dir_all(&run_dir).unwrap();
    let mut again = Cluster { children: vec![] };
    again.spawn(
        "learner",
        &bins.join("terl-learner"),
        &[
            "--config".to_string(),
            workspace()
                .join("deploy/configs/smoke-terl.toml")
                .display()
                .to_string(),
            "--run-id".into(),
            run_id.clone(),
            "--addr".into(),
            "127.0.0.1:0".into(),
            "--run-dir".into(),
            run_dir.display().to_string(),
            "--tep-dataset".into(),
            dataset.display().to_string(),
        ],
        &run_dir,
    );
    let learner = wait_for_file(&run_dir.join("learner.addr"));
    let (loaded, after_success) = (0..100)
        .find_map(|_| {
            std::thread::sleep(Duration::from_millis(100));
            let s = status(&learner, "127.0.0.1:1")?;
            let n = u(&s["learner"], &["tep_buffer_size"]);
            // The first trajectories of each task are held out for the planner check.
            let held: u64 = s["learner"]["planner"]["tasks"]
                .as_array()?
                .iter()
                .map(|t| t["held_out_transitions"].as_u64().unwrap_or(0))
                .sum();
            (n > 0).then_some((n + held, u(&s["learner"], &["tep_after_success"])))
        })
        .expect("the reloaded learner reports its TEP buffer");
    // Every sample is in the buffer, held out, or after its trajectory's first success: the
    // last counted from the file here, trajectory by trajectory.
    let mut by_trajectory: std::collections::BTreeMap<u64, Vec<(u32, bool)>> = Default::default();
    for x in &data.samples {
        by_trajectory
            .entry(x.trajectory_id)
            .or_default()
            .push((x.step, x.success));
    }
    let expected_after: u64 = by_trajectory
        .values_mut()
        .map(|steps| {
            steps.sort_unstable();
            steps
                .iter()
                .position(|&(_, success)| success)
                .map_or(0, |i| (steps.len() - i - 1) as u64)
        })
        .sum();
    eprintln!("reloaded: {loaded} in the buffer or held out, {after_success} after a success");
    assert_eq!(after_success, expected_after);
    assert_eq!(loaded + after_success, data.samples.len() as u64);
    stop_all(&mut again, &run_dir);

    let leftover: Vec<String> = shm_files().difference(&shm_before).cloned().collect();
    assert!(
        leftover.is_empty(),
        "shared-memory files left: {leftover:?}"
    );
}

/// MT50 on real processes (`deploy/configs/mt50-smoke.toml`, two actors): the one-hot spans
/// all 50 tasks, and episodes of every task reach both the learner and the selector, in
/// Meta-World's task order.
#[test]
fn mt50_cluster_trains_on_every_task() {
    let shm_before = shm_files();
    let mt50 = terl_sim::metaworld::task_set("mt50").unwrap();
    assert_eq!(mt50.len(), 50);
    let Running {
        mut cluster,
        run_dir,
        learner,
        selector,
        _dir,
        ..
    } = start("deploy/configs/mt50-smoke.toml", &[]);
    let start = Instant::now();
    let tasks_with_episodes = |v: &Value| -> Vec<(String, u64)> {
        v["task_success"]
            .as_array()
            .map(|ts| {
                ts.iter()
                    .map(|t| {
                        (
                            t["task"].as_str().unwrap_or("").to_string(),
                            u(t, &["episodes"]),
                        )
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    let mut last = Value::Null;
    loop {
        assert!(
            start.elapsed() < TIMEOUT,
            "not every task's episodes arrived in {TIMEOUT:?}; last status {last}; logs in {}",
            run_dir.display()
        );
        std::thread::sleep(Duration::from_millis(500));
        let Some(s) = status(&learner, &selector) else {
            continue;
        };
        let (l, sel) = (
            tasks_with_episodes(&s["learner"]),
            tasks_with_episodes(&s["selector"]),
        );
        for side in [&l, &sel] {
            if !side.is_empty() {
                let names: Vec<&str> = side.iter().map(|(t, _)| t.as_str()).collect();
                assert_eq!(names, mt50, "status lists the run's tasks in order");
            }
        }
        last = s;
        let all = |side: &[(String, u64)]| side.len() == 50 && side.iter().all(|(_, n)| *n > 0);
        if all(&l) && all(&sel) {
            break;
        }
    }
    eprintln!("every task's episodes arrived after {:?}", start.elapsed());
    let actors = last["learner"]["actors"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    assert_eq!(actors.len(), 2, "{last}");
    stop_all(&mut cluster, &run_dir);

    // The selector's episode log holds episodes of every task.
    let episodes =
        terl_telemetry::read_log::<terl_wire::EpisodeSummary>(run_dir.join("episodes.mcap"))
            .expect("episode log readable");
    let logged: BTreeSet<&str> = episodes.records.iter().map(|e| e.task.as_str()).collect();
    assert_eq!(logged, mt50.iter().copied().collect::<BTreeSet<_>>());
    let leftover: Vec<String> = shm_files().difference(&shm_before).cloned().collect();
    assert!(
        leftover.is_empty(),
        "shared-memory files left: {leftover:?}"
    );
}

/// The launcher runs `target/release` binaries: its tests fail in another profile instead of
/// passing without running.
fn require_release_build() {
    let release = Path::new(env!("CARGO_BIN_EXE_terl"))
        .parent()
        .and_then(Path::file_name)
        .is_some_and(|n| n == "release");
    assert!(
        release,
        "the launcher runs target/release binaries: run this test with --release \
         (./deploy/test.sh does)"
    );
}

/// The README's launcher on a run with a training budget: the learner stops by itself at
/// `train.total_env_steps`, and `deploy/local-cluster.sh` then stops the cluster and exits 0.
#[test]
fn launcher_stops_the_cluster_at_the_training_budget() {
    let shm_before = shm_files();
    service_binaries();
    let root = workspace();
    require_release_build();
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root.join("deploy/configs/cluster-smoke.toml")).unwrap();
    assert!(text.contains("warmup_env_steps = 1_000"));
    let config = dir.path().join("budget.toml");
    std::fs::write(
        &config,
        text.replace(
            "warmup_env_steps = 1_000",
            "total_env_steps = 4_000\nwarmup_env_steps = 1_000",
        ),
    )
    .unwrap();
    let run_id = format!("it-budget-{}", std::process::id());
    let start = Instant::now();
    let mut child = Command::new(root.join("deploy/local-cluster.sh"))
        .current_dir(&root)
        .args(["--config", config.to_str().unwrap(), "--actors", "1"])
        .args(["--run-id", &run_id, "--no-build"])
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
        if start.elapsed() > Duration::from_secs(120) {
            let _ = Command::new("kill")
                .args(["-INT", &child.id().to_string()])
                .status();
            panic!("the cluster did not stop at its budget");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    let run_dir = root.join("runs").join(&run_id);
    let final_ckpt = run_dir.join("checkpoints/final.safetensors").is_file();
    let _ = std::fs::remove_dir_all(&run_dir);
    assert!(status.success(), "launcher exited with {status}: {err}");
    assert!(
        err.contains("training budget") || err.contains("its budget or stop condition reached"),
        "{err}"
    );
    assert!(final_ckpt, "no final checkpoint");
    let leftover: Vec<String> = shm_files().difference(&shm_before).cloned().collect();
    assert!(
        leftover.is_empty(),
        "shared-memory files left: {leftover:?}"
    );
}

fn read_pids(run_dir: &Path) -> Vec<(String, u32)> {
    std::fs::read_to_string(run_dir.join("pids"))
        .unwrap_or_default()
        .lines()
        .filter_map(|l| {
            let (role, pid) = l.split_once(' ')?;
            Some((role.to_string(), pid.trim().parse().ok()?))
        })
        .collect()
}

fn alive(pid: u32) -> bool {
    Path::new(&format!("/proc/{pid}")).exists()
        && !std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .unwrap_or_default()
            .contains(") Z ")
}

fn wait_until(what: &str, limit: Duration, mut ok: impl FnMut() -> bool) {
    let start = Instant::now();
    while !ok() {
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn launcher(root: &Path, args: &[&str], log: &Path) -> Child {
    Command::new(root.join("deploy/local-cluster.sh"))
        .current_dir(root)
        .args(args)
        .arg("--no-build")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap()
}

/// TensorBoard's own reading (`event_accumulator`, `.deps/tensorboard-venv`) of the event files
/// in `dir`: `{"tags": {tag: [[step, value], ...]}, "files": n}`.
fn tensorboard(dir: &Path) -> Value {
    let root = workspace();
    let python = root.join(".deps/tensorboard-venv/bin/python");
    assert!(
        python.exists(),
        "{} is missing: run ./deploy/setup.sh",
        python.display()
    );
    let o = Command::new(python)
        .arg(root.join("crates/telemetry/tests/python/read_tensorboard.py"))
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// The env steps at which TensorBoard has the learner's `charts/env_steps`.
fn tensorboard_env_steps(run_dir: &Path) -> Vec<u64> {
    tensorboard(run_dir)["tags"]["charts/env_steps"]
        .as_array()
        .map(|a| a.iter().map(|p| p[0].as_u64().unwrap()).collect())
        .unwrap_or_default()
}

/// Faults injected into a launcher-run cluster, each survived: the learner killed with
/// SIGKILL is restarted and resumes from its last checkpoint (status says from which, the
/// update counter continues from it); the launcher itself killed with SIGKILL leaves no
/// orphan (the services follow its pid); `--resume` then continues the run, skipping a
/// newest checkpoint that was damaged for the previous one, the selector rebuilding its
/// windows from the episode logs; SIGTERM is reported as an interruption, not as the budget.
// One end-to-end scenario whose steps share the running cluster; split would repeat the set-up.
#[allow(clippy::too_many_lines)]
#[test]
fn killed_learner_is_restarted_and_runs_resume_past_a_damaged_checkpoint() {
    service_binaries();
    let root = workspace();
    require_release_build();
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(root.join("deploy/configs/cluster-smoke.toml")).unwrap();
    assert!(text.contains("checkpoint_every_secs = 5"));
    let config = dir.path().join("resume.toml");
    std::fs::write(
        &config,
        text.replace("checkpoint_every_secs = 5", "checkpoint_every_secs = 1"),
    )
    .unwrap();
    let runs = dir.path().join("runs");
    let run_id = format!("it-resume-{}", std::process::id());
    let run_dir = runs.join(&run_id);
    let limit = Duration::from_secs(90);
    let mut first = launcher(
        &root,
        &[
            "--config",
            config.to_str().unwrap(),
            "--actors",
            "1",
            "--run-id",
            &run_id,
            "--runs-root",
            runs.to_str().unwrap(),
            "--learner-addr",
            "127.0.0.1:0",
            "--selector-addr",
            "127.0.0.1:0",
            "--restarts",
            "2",
            "--restart-backoff",
            // Long enough that the actor notices the learner is gone and pauses.
            "3",
        ],
        &dir.path().join("first.log"),
    );
    let learner_addr = wait_for_file(&run_dir.join("learner.addr"));
    let selector_addr = wait_for_file(&run_dir.join("selector.addr"));
    let checkpoints = run_dir.join("checkpoints");
    let periodic = || -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(&checkpoints)
            .map(|d| d.filter_map(|e| e.ok()).map(|e| e.path()).collect())
            .unwrap_or_default();
        v.retain(|p| {
            p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with("update-"))
        });
        v.sort();
        v
    };
    // Training has gone on long enough for a checkpoint with updates in it.
    wait_until("a periodic checkpoint after some updates", limit, || {
        periodic().last().is_some_and(|p| {
            !p.to_string_lossy()
                .ends_with("update-0000000000.safetensors")
        }) && status(&learner_addr, &selector_addr)
            .is_some_and(|s| u(&s, &["learner", "updates"]) > 0)
    });
    // TensorBoard reads the live learner's scalars (keyed by env steps).
    let mut before_kill = Vec::new();
    wait_until("the learner's scalars in TensorBoard", limit, || {
        before_kill = tensorboard_env_steps(&run_dir);
        !before_kill.is_empty()
    });
    let pids = read_pids(&run_dir);
    let learner = pids.iter().find(|(r, _)| r == "learner").unwrap().1;
    let newest_before_kill = periodic().last().unwrap().clone();
    let steps_at: u64 = newest_before_kill
        .file_stem()
        .unwrap()
        .to_string_lossy()
        .trim_start_matches("update-")
        .parse()
        .unwrap();
    Command::new("kill")
        .args(["-9", &learner.to_string()])
        .status()
        .unwrap();

    // The launcher restarts it with --resume on the same address.
    let mut resumed = Value::Null;
    wait_until(
        "the restarted learner to report its resume",
        limit,
        || match status(&learner_addr, &selector_addr) {
            Some(s)
                if !s["learner"]["resumed_from"]
                    .as_str()
                    .unwrap_or("")
                    .is_empty() =>
            {
                resumed = s;
                true
            }
            _ => false,
        },
    );
    let at = u(&resumed, &["learner", "resumed_at_update"]);
    assert!(
        at >= steps_at && at > 0,
        "resumed at update {at}, newest checkpoint before the kill had {steps_at}"
    );
    assert!(u(&resumed, &["learner", "updates"]) >= at);
    let new_learner = read_pids(&run_dir)
        .into_iter()
        .find(|(r, _)| r == "learner")
        .unwrap()
        .1;
    assert_ne!(new_learner, learner);
    let cluster_txt = std::fs::read_to_string(run_dir.join("cluster.txt")).unwrap();
    assert!(
        cluster_txt.contains("role=learner exit_code=137"),
        "{cluster_txt}"
    );
    // `terl status --run` shows the launcher's processes (alive) and the restart.
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["status", "--json", "--run", run_dir.to_str().unwrap()])
        .output()
        .unwrap();
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    let restarts = v["launcher"]["restarts"].as_array().unwrap();
    assert_eq!(restarts.len(), 1, "{v}");
    assert!(restarts[0].as_str().unwrap().contains("role=learner"));
    let procs = v["launcher"]["processes"].as_array().unwrap();
    assert_eq!(procs.len(), 3);
    assert!(procs.iter().all(|p| p["alive"] == true), "{v}");
    // Each live process with its CPU use (in cores, between none and every core a process may
    // use) and resident memory (a learner holds at least its networks and the MuJoCo-free
    // runtime: well over 1 MB; an actor's environments well under 1 GB here).
    for p in procs {
        let cores = p["cpu_cores"].as_f64().unwrap_or(-1.0);
        let rss = p["rss_mb"].as_f64().unwrap_or(-1.0);
        assert!((0.0..=64.0).contains(&cores), "{p}");
        assert!((1.0..1000.0).contains(&rss), "{p}");
    }
    let text = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["status", "--run", run_dir.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("machine   ") && text.contains("the cluster uses") && text.contains("% CPU"),
        "{text}"
    );
    // Updates continue past the checkpoint once the replay buffer has refilled.
    wait_until("updates past the resume point", limit, || {
        status(&learner_addr, &selector_addr)
            .is_some_and(|s| u(&s, &["learner", "updates"]) > at + 50)
    });
    // TensorBoard still reads everything the killed learner wrote (its file ends where the
    // kill cut it), and the restarted learner's own file beside it.
    wait_until(
        "the restarted learner's scalars in TensorBoard",
        limit,
        || {
            let tb = tensorboard(&run_dir);
            let steps = tensorboard_env_steps(&run_dir);
            tb["files"] == 2
                && steps.len() > before_kill.len()
                && before_kill.iter().all(|s| steps.contains(s))
        },
    );
    // The in-run evaluations too, in their own folder.
    wait_until("the in-run evaluations in TensorBoard", limit, || {
        tensorboard(&run_dir.join("eval"))["tags"]["eval/mean_success_rate"]
            .as_array()
            .is_some_and(|a| !a.is_empty())
    });
    // The actor was not restarted: it waited for the restarted learner and rejoined.
    let actor = |pids: &[(String, u32)]| pids.iter().find(|(r, _)| r == "actor-0").map(|p| p.1);
    assert_eq!(
        actor(&read_pids(&run_dir)),
        actor(&pids),
        "the actor kept running"
    );
    // Whether it paused first depends on timing (a send blocked on the dead learner's full
    // queue may simply go on to the restarted one); either way it never failed.
    let actor_log = std::fs::read_to_string(run_dir.join("actor-0.log")).unwrap();
    assert!(
        !actor_log.contains("Error:"),
        "the actor failed:\n{actor_log}"
    );

    // SIGKILL the launcher: every service it started stops by itself.
    let services: Vec<u32> = read_pids(&run_dir).into_iter().map(|(_, p)| p).collect();
    assert_eq!(services.len(), 3, "learner, selector, one actor");
    first.kill().unwrap();
    first.wait().unwrap();
    wait_until("the services of a killed launcher to exit", limit, || {
        services.iter().all(|&p| !alive(p))
    });
    // Its files are left behind; `terl status` says no cluster runs instead of trying the
    // stale addresses (with --run, and by default through runs/.cluster.run).
    for args in [
        vec!["status", "--run", run_dir.to_str().unwrap()],
        vec!["status"],
    ] {
        let out = Command::new(env!("CARGO_BIN_EXE_terl"))
            .args(&args)
            .current_dir(dir.path())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success()
                && err.contains("no cluster is running")
                && err.contains("is gone"),
            "terl {args:?}: {err}"
        );
    }

    // Damage the newest checkpoint (it is final.safetensors, written on SIGTERM).
    let mut newest: Vec<PathBuf> = std::fs::read_dir(&checkpoints)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "safetensors"))
        .filter(|p| !p.to_string_lossy().ends_with("planner.safetensors"))
        .collect();
    newest.sort_by_key(|p| std::fs::metadata(p).unwrap().modified().unwrap());
    let damaged = newest.last().unwrap().clone();
    let mut bytes = std::fs::read(&damaged).unwrap();
    let n = bytes.len();
    bytes[n - 5] ^= 0x55;
    std::fs::write(&damaged, &bytes).unwrap();

    let _ = std::fs::remove_file(run_dir.join("learner.addr"));
    let _ = std::fs::remove_file(run_dir.join("selector.addr"));
    let mut second = launcher(
        &root,
        &["--resume", run_dir.to_str().unwrap(), "--restarts", "0"],
        &dir.path().join("second.log"),
    );
    let learner_addr = wait_for_file(&run_dir.join("learner.addr"));
    let selector_addr = wait_for_file(&run_dir.join("selector.addr"));
    wait_until("the resumed run's status", limit, || {
        status(&learner_addr, &selector_addr).is_some_and(|s| {
            let from = s["learner"]["resumed_from"]
                .as_str()
                .unwrap_or("")
                .to_string();
            resumed = s;
            !from.is_empty()
        })
    });
    let from = resumed["learner"]["resumed_from"]
        .as_str()
        .unwrap()
        .to_string();
    assert_ne!(
        Path::new(&from),
        damaged,
        "resumed from the damaged checkpoint"
    );
    let learner_log = std::fs::read_to_string(run_dir.join("learner.log")).unwrap();
    assert!(
        learner_log.contains("damaged") && learner_log.contains(&*damaged.to_string_lossy()),
        "no log line about the damaged checkpoint"
    );
    // The selector writes its address before it has read the episode logs back: wait for the
    // line rather than reading the log once.
    wait_until("the selector to resume its success windows", limit, || {
        std::fs::read_to_string(run_dir.join("selector.log"))
            .is_ok_and(|log| log.contains("resumed the success windows"))
    });
    assert!(run_dir.join("metrics.2.mcap").exists() || run_dir.join("metrics.3.mcap").exists());

    Command::new("kill")
        .args(["-TERM", &second.id().to_string()])
        .status()
        .unwrap();
    let code = second.wait().unwrap();
    let log = std::fs::read_to_string(dir.path().join("second.log")).unwrap();
    assert_eq!(code.code(), Some(143), "{log}");
    assert!(
        log.contains("interrupted") && !log.contains("total_env_steps reached"),
        "{log}"
    );
}

/// The launcher refuses what would go wrong later: a run id the services would refuse (before
/// it is used in a process search), a run id whose lock another launcher holds (two launchers
/// started in the same instant both passed the process search), and a learner that cannot
/// start (a non-loopback address without a token) is reported with its error as soon as it
/// exits, without a restart.
#[test]
fn launcher_refuses_bad_or_locked_run_ids_and_reports_a_start_up_failure_with_its_error() {
    service_binaries();
    let root = workspace();
    require_release_build();
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let locks = dir.path().join("tmp");
    std::fs::create_dir_all(&locks).unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(root.join("deploy/local-cluster.sh"))
            .current_dir(&root)
            .env("TMPDIR", &locks)
            .args([
                "--config",
                "deploy/configs/cluster-smoke.toml",
                "--no-build",
            ])
            .args(["--runs-root", runs.to_str().unwrap()])
            .args(args)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        )
    };

    for bad in ["bk(p", "a/b", ".."] {
        let (code, err) = run(&["--run-id", bad]);
        assert_eq!(code, Some(2), "{bad:?}: {err}");
        assert!(
            err.contains("--run-id") && err.contains("must be 1 to 64 characters"),
            "{bad:?}: {err}"
        );
    }
    for (flag, bad) in [
        ("--actors", "0"),
        ("--actors", "07"),
        ("--actors", "two"),
        ("--restarts", "three"),
        ("--restart-backoff", "1.5"),
    ] {
        let (code, err) = run(&[flag, bad, "--run-id", "it-bad-option"]);
        assert_eq!(code, Some(2), "{flag} {bad}: {err}");
        assert!(
            err.contains(flag) && err.contains("must be"),
            "{flag} {bad}: {err}"
        );
        assert!(!runs.join("it-bad-option").exists(), "nothing was started");
    }
    // --resume of a folder that is not a launcher's run folder (no cluster.txt), and of one
    // with logs but no checkpoint (it would start again from update 0 beside the old logs).
    let config_only = dir.path().join("config-only");
    std::fs::create_dir_all(&config_only).unwrap();
    std::fs::copy(
        root.join("deploy/configs/cluster-smoke.toml"),
        config_only.join("config.toml"),
    )
    .unwrap();
    let resume = |folder: &Path| {
        let out = Command::new(root.join("deploy/local-cluster.sh"))
            .current_dir(&root)
            .env("TMPDIR", &locks)
            .args(["--no-build", "--resume"])
            .arg(folder)
            .output()
            .unwrap();
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stderr).to_string(),
        )
    };
    let (code, err) = resume(&config_only);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("cluster.txt not found"), "{err}");
    assert!(
        !config_only.join("cluster.txt").exists(),
        "nothing was written"
    );
    std::fs::write(config_only.join("cluster.txt"), "run_id=config-only\n").unwrap();
    std::fs::write(config_only.join("episodes.mcap"), b"").unwrap();
    let (code, err) = resume(&config_only);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("holds logs but no checkpoint"), "{err}");
    // More actors than the machine can hold: refused before anything starts.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    for too_many in [(4 * cores + 1).to_string(), "100000".to_string()] {
        let (code, err) = run(&["--actors", &too_many, "--run-id", "it-too-many"]);
        assert_eq!(code, Some(2), "--actors {too_many}: {err}");
        assert!(err.contains("local actors"), "--actors {too_many}: {err}");
        assert!(!runs.join("it-too-many").exists(), "nothing was started");
    }
    // A run file the services would refuse (a misspelt key; an unknown task) is refused by the
    // launcher, naming the problem, before it writes a run folder.
    let smoke = std::fs::read_to_string(root.join("deploy/configs/cluster-smoke.toml")).unwrap();
    let misspelt = dir.path().join("misspelt.toml");
    std::fs::write(
        &misspelt,
        smoke.replace("checkpoint_every_secs = 5", "checkpoint_evry_secs = 5"),
    )
    .unwrap();
    let unknown_task = dir.path().join("unknown-task.toml");
    let tasks_line = smoke
        .lines()
        .find(|l| l.starts_with("tasks"))
        .expect("the smoke run file names its tasks");
    std::fs::write(
        &unknown_task,
        smoke.replace(tasks_line, "tasks = \"reach-v3,no-such-task-v3\""),
    )
    .unwrap();
    for (file, expected) in [
        (&misspelt, "checkpoint_evry_secs"),
        (&unknown_task, "no-such-task-v3"),
    ] {
        let out = Command::new(root.join("deploy/local-cluster.sh"))
            .current_dir(&root)
            .env("TMPDIR", &locks)
            .args(["--config", file.to_str().unwrap(), "--no-build"])
            .args([
                "--runs-root",
                runs.to_str().unwrap(),
                "--run-id",
                "it-bad-file",
            ])
            .output()
            .unwrap();
        let (code, err) = (out.status.code(), String::from_utf8_lossy(&out.stderr));
        assert_eq!(code, Some(2), "{}: {err}", file.display());
        assert!(err.contains(expected), "{}: {err}", file.display());
        assert!(
            !runs.join("it-bad-file").exists(),
            "a refused run file made a run folder"
        );
    }

    // A fresh run into another run's folder: refused, the folder untouched (its checkpoints
    // would be rotated away and a later --resume could continue either run).
    let taken = runs.join("it-taken");
    std::fs::create_dir_all(taken.join("checkpoints")).unwrap();
    std::fs::write(
        taken.join("checkpoints/update-0000000010.safetensors"),
        b"x",
    )
    .unwrap();
    let (code, err) = run(&["--run-id", "it-taken"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("already holds files") && err.contains("--resume"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_dir(&taken).unwrap().count(),
        1,
        "nothing was written"
    );
    // A dangling link under the run's name is named as what it is, and left alone.
    let link = runs.join("it-link");
    std::os::unix::fs::symlink("nowhere", &link).unwrap();
    let (code, err) = run(&["--run-id", "it-link"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("is a link, not a folder") && !err.contains("--resume"),
        "a link is not offered for --resume: {err}"
    );
    assert!(std::fs::symlink_metadata(&link)
        .unwrap()
        .file_type()
        .is_symlink());

    // Resuming on a smaller machine a run that recorded more actors than it can run: the
    // message names the run's cluster.txt as the source of the count, not --actors.
    let big = runs.join("it-resume-big");
    std::fs::create_dir_all(&big).unwrap();
    std::fs::copy(
        root.join("deploy/configs/cluster-smoke.toml"),
        big.join("config.toml"),
    )
    .unwrap();
    std::fs::write(
        big.join("cluster.txt"),
        "run_id=it-resume-big\nactors=100000\n",
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .current_dir(&root)
        .env("TMPDIR", &locks)
        .args(["cluster", "up", "--resume"])
        .arg(&big)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("cluster.txt says actors=100000") && err.contains("give --actors"),
        "{err}"
    );
    assert!(!err.contains("--actors 100000"), "{err}");

    // Another launcher of this run id holds its lock.
    let id = format!("it-lock-{}", std::process::id());
    let lock = locks.join("terl-run-locks").join(format!("{id}.lock"));
    std::fs::create_dir_all(lock.parent().unwrap()).unwrap();
    // `flock` and its `sleep` in a process group of their own, so both go at once below.
    let mut holder = {
        use std::os::unix::process::CommandExt;
        Command::new("flock")
            .arg(&lock)
            .args(["sleep", "60"])
            .process_group(0)
            .spawn()
            .unwrap()
    };
    wait_until("the lock to be held", Duration::from_secs(10), || {
        Command::new("flock")
            .args(["-n", lock.to_str().unwrap(), "true"])
            .status()
            .is_ok_and(|s| !s.success())
    });
    let (code, err) = run(&["--run-id", &id]);
    // The process group goes as a whole: `-s KILL -- -<pgid>`. (procps' kill reads
    // `-KILL -<pgid>` as `kill(-<first digit>, SIGKILL)`, and with a pgid starting with 1
    // that is kill(-1): every process the test may signal.)
    let killed = Command::new("kill")
        .args(["-s", "KILL", "--", &format!("-{}", holder.id())])
        .status()
        .unwrap();
    assert!(
        killed.success(),
        "kill of the lock holder's group: {killed}"
    );
    holder.wait().unwrap();
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("is in use by another launcher"), "{err}");
    assert!(
        !runs.join(&id).exists(),
        "a refused launcher made a run folder"
    );

    // Free lock, but a learner that must refuse to start: reported with its error, no restart.
    let (code, err) = run(&[
        "--run-id",
        &id,
        "--learner-addr",
        "0.0.0.0:0",
        "--restarts",
        "3",
    ]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("learner did not start"), "{err}");
    assert!(err.contains("token"), "the learner's error is shown: {err}");
    assert!(!err.contains("restart 1 of"), "{err}");
    assert!(!err.contains("stack backtrace"), "{err}");
}

/// `terl cluster up` on the smoke config with one actor in `runs` (a runs root of its own),
/// stderr to `log`; returns once the launcher says the run started (learner and selector
/// answer health).
fn cluster_up(root: &Path, runs: &Path, run_id: &str, log: &Path) -> Child {
    let mut child = Command::new(env!("CARGO_BIN_EXE_terl"))
        .current_dir(root)
        .args([
            "cluster",
            "up",
            "--config",
            "deploy/configs/cluster-smoke.toml",
        ])
        .args(["--actors", "1", "--run-id", run_id])
        .args(["--runs-root", runs.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap();
    let started = format!("[cluster] run {run_id} started");
    let start = Instant::now();
    while !std::fs::read_to_string(log)
        .unwrap_or_default()
        .contains(&started)
    {
        if start.elapsed() > Duration::from_secs(90) || child.try_wait().unwrap().is_some() {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "the cluster did not start:\n{}",
                std::fs::read_to_string(log).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    child
}

fn terl(args: &[&str], cwd: &Path) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

/// `terl cluster down ID` stops the run it names: the launcher stops every process, says it
/// was interrupted, and exits 0 (a stop that was asked for). `terl cluster clean ID` refuses
/// while the run is alive, and afterwards removes the address files the stopped run left.
#[test]
fn cluster_down_exits_0_and_clean_refuses_a_live_run() {
    service_binaries();
    let root = workspace();
    require_release_build();
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let runs_s = runs.to_str().unwrap();
    let run_id = format!("it-down-{}", std::process::id());
    let run_dir = runs.join(&run_id);
    let log = dir.path().join("up.log");
    let mut up = cluster_up(&root, &runs, &run_id, &log);
    let services: Vec<u32> = read_pids(&run_dir).into_iter().map(|(_, p)| p).collect();
    assert_eq!(services.len(), 3, "learner, selector, one actor");
    assert!(services.iter().all(|&p| alive(p)));
    assert_eq!(
        std::fs::read_to_string(run_dir.join("launcher.pid"))
            .unwrap()
            .trim(),
        up.id().to_string()
    );

    let (code, err) = terl(
        &["cluster", "clean", &run_id, "--runs-root", runs_s],
        dir.path(),
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("is running"), "{err}");
    assert!(run_dir.join("launcher.pid").exists() && run_dir.join("learner.addr").exists());

    let (code, err) = terl(
        &["cluster", "down", &run_id, "--runs-root", runs_s],
        dir.path(),
    );
    assert_eq!(code, Some(0), "{err}");
    let start = Instant::now();
    let status = loop {
        if let Some(s) = up.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = up.kill();
            panic!("the launcher did not stop after terl cluster down");
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let text = std::fs::read_to_string(&log).unwrap();
    assert_eq!(status.code(), Some(0), "{text}");
    assert!(
        text.contains("[cluster] stopped: interrupted") && text.contains("worst exit code 0"),
        "{text}"
    );
    assert!(
        services.iter().all(|&p| !alive(p)),
        "a service outlived its launcher"
    );
    for gone in ["launcher.pid", "pids"] {
        assert!(!run_dir.join(gone).exists(), "{gone} left");
    }
    assert!(!runs.join(".cluster.pid").exists() && !runs.join(".cluster.run").exists());

    // The stopped run's address files go with clean, nothing else does.
    let (code, err) = terl(
        &["cluster", "clean", &run_id, "--runs-root", runs_s],
        dir.path(),
    );
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("learner.addr"), "{err}");
    assert!(!run_dir.join("learner.addr").exists() && !run_dir.join("selector.addr").exists());
    assert!(run_dir.join("config.toml").exists() && run_dir.join("learner.log").exists());
}

/// `terl cluster up` killed with SIGKILL leaves no service alive (they follow its pid); `terl
/// status` says the launcher is gone; `terl cluster down` refuses its stale pid; `terl cluster
/// clean` removes its pid, address and `.cluster.*` files.
#[test]
fn killed_terl_cluster_up_leaves_no_service_and_clean_removes_its_files() {
    service_binaries();
    let root = workspace();
    require_release_build();
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let runs_s = runs.to_str().unwrap();
    let run_id = format!("it-kill-{}", std::process::id());
    let run_dir = runs.join(&run_id);
    let mut up = cluster_up(&root, &runs, &run_id, &dir.path().join("up.log"));
    let services: Vec<u32> = read_pids(&run_dir).into_iter().map(|(_, p)| p).collect();
    assert_eq!(services.len(), 3, "learner, selector, one actor");
    up.kill().unwrap();
    up.wait().unwrap();
    wait_until(
        "the services of a killed launcher to exit",
        Duration::from_secs(60),
        || services.iter().all(|&p| !alive(p)),
    );

    let (code, err) = terl(&["status"], dir.path());
    assert!(
        code != Some(0) && err.contains("no cluster is running") && err.contains("is gone"),
        "{err}"
    );
    let (code, err) = terl(
        &["cluster", "down", &run_id, "--runs-root", runs_s],
        dir.path(),
    );
    assert!(code != Some(0) && err.contains("stale"), "{err}");

    let left = [
        run_dir.join("launcher.pid"),
        run_dir.join("pids"),
        run_dir.join("learner.addr"),
        run_dir.join("selector.addr"),
        runs.join(".cluster.pid"),
        runs.join(".cluster.run"),
    ];
    assert!(
        left.iter().all(|f| f.exists()),
        "the killed launcher's files"
    );
    let (code, err) = terl(
        &["cluster", "clean", &run_id, "--runs-root", runs_s],
        dir.path(),
    );
    assert_eq!(code, Some(0), "{err}");
    for f in &left {
        assert!(!f.exists(), "{} left after clean", f.display());
    }
    assert!(run_dir.join("cluster.txt").exists());
}

/// A tmpfs mounted for one test; unmounted (lazily, so a process still holding a file cannot
/// keep it) on drop.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(at: &Path, size: &str) -> Tmpfs {
        std::fs::create_dir_all(at).unwrap();
        let out = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(at)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "cannot mount a tmpfs at {} (needs root, as ./deploy/test.sh and CI run): {}",
            at.display(),
            String::from_utf8_lossy(&out.stderr)
        );
        Tmpfs(at.to_path_buf())
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// Writes zeros into `path` until the filesystem refuses more; returns the bytes written.
fn fill(path: &Path) -> u64 {
    use std::io::Write;
    let mut f = std::fs::File::create(path).unwrap();
    let chunk = vec![0u8; 64 * 1024];
    let mut written = 0u64;
    loop {
        match f.write(&chunk) {
            Ok(0) => break,
            Ok(n) => written += n as u64,
            Err(e) => {
                assert_eq!(e.raw_os_error(), Some(28), "filling: {e}"); // ENOSPC
                break;
            }
        }
    }
    let _ = f.sync_all();
    written
}

/// The run folder's disk fills up while every service writes into it (the learner its
/// checkpoints, metrics and log, the selector its episode log and log, the actor its log):
/// no process panics or has to be killed, the launcher stops the cluster once, says that the
/// filesystem is full and how to go on, and leaves no process behind.
#[test]
fn a_full_disk_stops_the_cluster_with_the_reason_and_no_panic() {
    service_binaries();
    let root = workspace();
    require_release_build();
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let _tmpfs = Tmpfs::mount(&runs, "64m");
    let run_id = format!("it-full-{}", std::process::id());
    let run_dir = runs.join(&run_id);
    let log = dir.path().join("up.log");
    let mut up = cluster_up(&root, &runs, &run_id, &log);
    let services: Vec<u32> = read_pids(&run_dir).into_iter().map(|(_, p)| p).collect();
    assert_eq!(services.len(), 3, "learner, selector, one actor");
    // Running for real: a checkpoint and episodes on disk.
    let start = Instant::now();
    while !(run_dir
        .join("checkpoints")
        .read_dir()
        .is_ok_and(|mut d| d.next().is_some())
        && run_dir
            .join("episodes.mcap")
            .metadata()
            .is_ok_and(|m| m.len() > 0))
    {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no checkpoint and episodes within 120 s:\n{}",
            std::fs::read_to_string(&log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    eprintln!(
        "after {:.1} s: running, with a checkpoint",
        start.elapsed().as_secs_f64()
    );
    let filled = fill(&runs.join("filler"));
    assert!(filled > 0);
    eprintln!("disk filled ({filled} bytes)");

    let start = Instant::now();
    let status = loop {
        if let Some(s) = up.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(120) {
            let _ = up.kill();
            panic!(
                "the launcher did not stop within 120 s of a full disk:\n{}",
                std::fs::read_to_string(&log).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let err = std::fs::read_to_string(&log).unwrap();
    eprintln!(
        "after {:.1} s: the launcher stopped",
        start.elapsed().as_secs_f64()
    );
    assert_eq!(status.code(), Some(1), "{err}");
    assert!(err.contains("filesystem is full"), "{err}");
    assert!(err.contains("--resume"), "says how to go on: {err}");
    // Every process ended by itself or on SIGTERM, with an error code at worst: not a panic
    // (101), not a signal, not the launcher's SIGKILL after the grace period (137).
    let worst = err
        .split("worst exit code ")
        .nth(1)
        .and_then(|s| s.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|s| s.parse::<i32>().ok())
        .unwrap_or_else(|| panic!("no worst exit code in: {err}"));
    assert!(worst <= 1, "a process ended with code {worst}:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    // What reached the logs: no panic, and a service that ended with an error names the
    // cause, not only the file it could not write. The logs live on the full disk too: a log
    // whose last line was cut (no final newline) could not hold the cause, so only a log
    // written whole is held to it.
    for name in ["learner.log", "selector.log", "actor-0.log"] {
        let text = std::fs::read_to_string(run_dir.join(name)).unwrap_or_default();
        assert!(!text.contains("panicked"), "{name}:\n{text}");
        let whole = text.is_empty() || text.ends_with('\n');
        if let Some(at) = text.find("Error: ").filter(|_| whole) {
            assert!(
                text[at..].contains("No space left on device"),
                "{name} ends with an error that does not say why:\n{}",
                &text[at..]
            );
        }
    }
    for pid in services {
        assert!(!alive(pid), "pid {pid} is still running");
    }

    // A new run on the still-full disk is refused before anything is written or started.
    let again = format!("{run_id}-again");
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .current_dir(&root)
        .args([
            "cluster",
            "up",
            "--config",
            "deploy/configs/cluster-smoke.toml",
        ])
        .args(["--actors", "1", "--run-id", &again, "--no-build"])
        .args(["--runs-root", runs.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("filesystem is full"), "{err}");
    assert!(!runs.join(&again).exists(), "a run folder was left: {err}");
}
