//! No silent loss, with real processes over real shared memory:
//!
//! - a learner stopped (SIGSTOP) for longer than `[cluster] block_timeout_secs` makes the
//!   actor's sends time out; the actor counts every dropped batch, transition and episode, and
//!   once the learner runs again the counts reach `terl status` (per actor and summed), the
//!   selector's status and the learner's `metrics.mcap`, equal to what the actor logged;
//! - a second actor started with an id that is already streaming to the run is refused with
//!   a clear message and a non-zero exit, while the first keeps running.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

mod common;

use common::{service_binaries, workspace};

/// Upper bound on any wait; the conditions normally hold much sooner.
const TIMEOUT: Duration = Duration::from_secs(120);

/// Children killed on drop, so a failed assertion leaves no process behind.
struct Children(Vec<Child>);

impl Drop for Children {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = Command::new("kill")
                .args(["-CONT", &c.id().to_string()])
                .status();
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn signal(child: &Child, sig: &str) {
    let ok = Command::new("kill")
        .args([sig, &child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill {sig} failed");
}

fn spawn(bin: &Path, args: &[String], log: &Path) -> Child {
    Command::new(bin)
        .args(args)
        .env("RUST_LOG", "info")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()))
}

fn wait_until<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(start.elapsed() < TIMEOUT, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

/// Waits for `child` to exit on its own; its exit status.
fn wait_exit(child: &mut Child, what: &str) -> std::process::ExitStatus {
    wait_until(what, || child.try_wait().unwrap())
}

fn status(learner: &str, selector: &str) -> Option<Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["status", "--json", "--addr", learner])
        .args(["--selector-addr", selector])
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| serde_json::from_slice(&out.stdout).ok())
        .flatten()
}

fn u(v: &Value, path: &[&str]) -> u64 {
    path.iter().fold(v, |v, p| &v[p]).as_u64().unwrap_or(0)
}

/// `(dropped, dropped_items)` of every block-timeout warning the actor logged for `stream`
/// (running totals, in order).
fn logged_totals(log: &str, run_id: &str, stream: &str) -> Vec<(u64, u64)> {
    let service = format!("terl/{run_id}/{stream} blocked");
    let field = |line: &str, name: &str| -> u64 {
        let start = line.find(&format!(" {name}=")).expect(name) + name.len() + 2;
        line[start..]
            .split(|c: char| !c.is_ascii_digit())
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    log.lines()
        .filter(|l| l.contains(&service))
        .map(|l| (field(l, "dropped"), field(l, "dropped_items")))
        .collect()
}

fn unique_run(name: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("{name}-{}-{nanos}", std::process::id())
}

/// cluster-smoke.toml with a short block timeout and no in-run evaluation.
fn config(dir: &Path) -> PathBuf {
    let text = read(&workspace().join("deploy/configs/cluster-smoke.toml"));
    for needle in ["block_timeout_secs = 10", "eval_every_env_steps = 2_000"] {
        assert!(
            text.contains(needle),
            "cluster-smoke.toml changed: {needle}"
        );
    }
    let text = text
        .replace("block_timeout_secs = 10", "block_timeout_secs = 0.2")
        .replace("eval_every_env_steps = 2_000", "eval_every_env_steps = 0");
    let path = dir.join("lossy.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_stalled_learner_loses_nothing_silently() {
    let bins = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = config(dir.path());
    let run_id = unique_run("loss");
    let run_dir = dir.path().join(&run_id);
    std::fs::create_dir_all(&run_dir).unwrap();
    let args = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = vec![
            "--config".into(),
            config.display().to_string(),
            "--run-id".into(),
            run_id.clone(),
            "--num-actors".into(),
            "1".into(),
        ];
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run_dir_s = run_dir.display().to_string();
    let server = ["--addr", "127.0.0.1:0", "--run-dir", &run_dir_s];
    let mut children = Children(vec![]);
    children.0.push(spawn(
        &bins.join("terl-learner"),
        &args(&server),
        &run_dir.join("learner.log"),
    ));
    let learner = wait_until("learner.addr", || {
        Some(read(&run_dir.join("learner.addr")).trim().to_string()).filter(|s| !s.is_empty())
    });
    children.0.push(spawn(
        &bins.join("terl-selector"),
        &args(&server),
        &run_dir.join("selector.log"),
    ));
    let selector = wait_until("selector.addr", || {
        Some(read(&run_dir.join("selector.addr")).trim().to_string()).filter(|s| !s.is_empty())
    });
    let actor_log = run_dir.join("actor0.log");
    children.0.push(spawn(
        &bins.join("terl-actor"),
        &args(&["--actor-id", "0", "--learner-addr", &learner]),
        &actor_log,
    ));
    wait_until("transitions at the learner", || {
        status(&learner, &selector).filter(|s| u(s, &["learner", "env_steps_total"]) > 0)
    });

    // The learner stops: its transition and episode queues fill, the actor's sends time out.
    signal(&children.0[0], "-STOP");
    wait_until("dropped transition batches and episodes", || {
        let log = read(&actor_log);
        let t = logged_totals(&log, &run_id, "transitions");
        let e = logged_totals(&log, &run_id, "episodes");
        (t.len() >= 3 && !e.is_empty()).then_some(())
    });
    signal(&children.0[0], "-CONT");

    // The next delivered batch and episode carry the actor's totals to the learner.
    let s = wait_until("drop counts in terl status", || {
        status(&learner, &selector).filter(|s| {
            u(s, &["learner", "transitions_dropped"]) > 0
                && u(s, &["learner", "episodes_dropped"]) > 0
                && u(s, &["selector", "episodes_dropped"]) > 0
        })
    });
    eprintln!("status after the stall: {s:#}");
    let log = read(&actor_log);
    let transitions = logged_totals(&log, &run_id, "transitions");
    let episodes = logged_totals(&log, &run_id, "episodes");
    eprintln!("actor logged {transitions:?} and {episodes:?}");
    let l = &s["learner"];
    let actor = &l["actors"][0];
    assert_eq!(u(actor, &["actor_id"]), 0);
    let batches = u(actor, &["transition_batches_dropped"]);
    let dropped = u(actor, &["transitions_dropped"]);
    // The learner shows exactly a total the actor had counted when it sent a later batch.
    assert!(
        transitions.contains(&(batches, dropped)),
        "status says {batches} batches / {dropped} transitions dropped; actor logged {transitions:?}"
    );
    // Actors send full batches only.
    assert_eq!(dropped, 64 * batches);
    assert_eq!(
        (
            u(l, &["transition_batches_dropped"]),
            u(l, &["transitions_dropped"])
        ),
        (batches, dropped)
    );
    let eps = u(actor, &["episodes_dropped"]);
    assert!(episodes.contains(&(eps, eps)), "{eps} vs {episodes:?}");
    assert_eq!(u(l, &["episodes_dropped"]), eps);
    let sel = &s["selector"];
    let sel_eps = u(sel, &["episodes_dropped"]);
    assert!(
        episodes.contains(&(sel_eps, sel_eps)),
        "{sel_eps} vs {episodes:?}"
    );
    // Only the learner stalled: the selector itself received every episode.
    assert_eq!(u(sel, &["episodes_missed"]), 0);
    let table = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["status", "--addr", &learner, "--selector-addr", &selector])
        .output()
        .unwrap();
    let table = String::from_utf8_lossy(&table.stdout);
    assert!(table.contains("never reached the learner"), "{table}");

    // The learner's metrics log has the counts too (one sample per status window).
    let logged = |name: &str| -> u64 {
        terl_telemetry::read_log::<terl_wire::Metric>(run_dir.join("metrics.mcap"))
            .map(|m| {
                m.records
                    .iter()
                    .filter(|m| m.name == name)
                    .map(|m| m.value as u64)
                    .max()
                    .unwrap_or(0)
            })
            .unwrap_or(0)
    };
    wait_until("drop counts in metrics.mcap", || {
        (logged("transport/transitions_dropped") >= dropped
            && logged("transport/transitions_dropped/actor-0") >= dropped
            && logged("transport/transition_batches_dropped") >= batches
            && logged("transport/episodes_dropped") >= eps)
            .then_some(())
    });
    for c in &children.0 {
        signal(c, "-TERM");
    }
    for c in &mut children.0 {
        let status = wait_exit(c, "the cluster to stop");
        assert!(status.success(), "a process exited with {status}");
    }
}

#[test]
fn a_second_actor_with_a_streaming_id_is_refused() {
    let bins = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = workspace().join("deploy/configs/cluster-smoke.toml");
    let run_id = unique_run("dup");
    let actor = |id: &str| -> Vec<String> {
        [
            "--config",
            config.to_str().unwrap(),
            "--run-id",
            &run_id,
            "--num-actors",
            "2",
            "--actor-id",
            id,
            // Nothing listens there: the actors stream without weights.
            "--learner-addr",
            "127.0.0.1:1",
        ]
        .map(str::to_string)
        .to_vec()
    };
    let first_log = dir.path().join("first.log");
    let mut children = Children(vec![spawn(
        &bins.join("terl-actor"),
        &actor("0"),
        &first_log,
    )]);
    wait_until("the first actor to start", || {
        read(&first_log).contains("actor started").then_some(())
    });

    let mut second = Command::new(bins.join("terl-actor"))
        .args(actor("0"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = second.stderr.take().unwrap();
    let status = wait_exit(&mut second, "the second actor to exit");
    let text: Vec<String> = BufReader::new(stderr)
        .lines()
        .map_while(Result::ok)
        .collect();
    let text = text.join("\n");
    assert!(!status.success(), "a second actor 0 was accepted: {text}");
    assert!(
        text.contains(&format!("actor id 0 is already streaming to run {run_id}")),
        "{text}"
    );
    assert!(
        children.0[0].try_wait().unwrap().is_none(),
        "the first actor stopped: {}",
        read(&first_log)
    );

    // Another id is fine.
    let other_log = dir.path().join("other.log");
    children
        .0
        .push(spawn(&bins.join("terl-actor"), &actor("1"), &other_log));
    wait_until("actor 1 to start", || {
        read(&other_log).contains("actor started").then_some(())
    });
    for c in &children.0 {
        signal(c, "-TERM");
    }
    for c in &mut children.0 {
        let status = wait_exit(c, "an actor to stop");
        assert!(status.success(), "actor exited with {status}");
    }
}
