//! Actors on another host, for real: two network namespaces joined by a veth pair, the
//! learner and selector in one, an actor in the other, transitions and episodes over Zenoh,
//! weights and status over gRPC. Checks that transitions flow, weights arrive (the actor's
//! policy version grows), status answers, and that taking the link down until the actor gives
//! something up, and up again, is survived with exactly what was given up reported. Needs root (`ip netns`); fails
//! where namespaces cannot be created. Everything it creates (namespaces,
//! veths, processes) is removed by a guard, also on failure.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

mod common;

use common::{service_binaries, workspace};

/// The learner and selector serve a non-loopback address here, which needs a token.
const TOKEN: &str = "netns-test-token-0123456789abcdef";

/// Namespaces and processes of one test run; removed on drop.
struct Net {
    namespaces: Vec<String>,
    children: Vec<Child>,
}

impl Drop for Net {
    fn drop(&mut self) {
        for child in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
        // Deleting a namespace deletes the veth end inside it, and with it the pair.
        for ns in &self.namespaces {
            let _ = Command::new("ip").args(["netns", "del", ns]).status();
        }
    }
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

impl Net {
    fn spawn(&mut self, ns: &str, bin: &Path, args: &[String], log: &Path) {
        let child = spawn_in(ns, bin, args, log, TOKEN);
        self.children.push(child);
    }
}

/// Starts `bin` in namespace `ns` with `token` as TERL_TOKEN, its stderr to `log`.
fn spawn_in(ns: &str, bin: &Path, args: &[String], log: &Path, token: &str) -> Child {
    let log = std::fs::File::create(log).unwrap();
    Command::new("ip")
        .args(["netns", "exec", ns])
        .arg(bin)
        .args(args)
        .env("RUST_LOG", "info")
        .env("TERL_TOKEN", token)
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap()
}

/// Waits up to 90 s for a process that must stop on its own; its exit status and log.
fn exit_of(mut child: Child, log: &Path) -> (std::process::ExitStatus, String) {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return (status, std::fs::read_to_string(log).unwrap_or_default());
        }
        if start.elapsed() > Duration::from_secs(90) {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "still running after 90 s:\n{}",
                std::fs::read_to_string(log).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn wait_for_file(path: &Path) -> String {
    let start = Instant::now();
    loop {
        if let Ok(text) = std::fs::read_to_string(path) {
            if !text.trim().is_empty() {
                return text.trim().to_string();
            }
        }
        if start.elapsed() > Duration::from_secs(60) {
            let dir = path.parent().unwrap();
            let logs: Vec<String> = std::fs::read_dir(dir)
                .unwrap()
                .flatten()
                .filter(|e| e.path().extension().is_some_and(|x| x == "log"))
                .map(|e| {
                    let text = std::fs::read_to_string(e.path()).unwrap_or_default();
                    format!("--- {}\n{text}", e.path().display())
                })
                .collect();
            panic!("{} never appeared\n{}", path.display(), logs.join("\n"));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The run's CA (`terl certs`), set once the test has made it.
static CA: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();

fn status(ns: &str, learner: &str, selector: &str) -> Option<Value> {
    let out = Command::new("ip")
        .args(["netns", "exec", ns, env!("CARGO_BIN_EXE_terl")])
        .env("TERL_TOKEN", TOKEN)
        .args([
            "status",
            "--json",
            "--addr",
            learner,
            "--selector-addr",
            selector,
        ])
        .arg("--tls-ca")
        .arg(CA.get().expect("the run's CA"))
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| serde_json::from_slice(&out.stdout).ok())
        .flatten()
}

fn u(v: &Value, key: &str) -> u64 {
    v[key].as_u64().unwrap_or(0)
}

/// Polls status until `cond` holds (up to `limit`), returning that status; on time-out the
/// last status and the run's logs are in the panic message.
fn until(
    ns: &str,
    l: &str,
    s: &str,
    what: &str,
    limit: Duration,
    logs: &Path,
    cond: impl Fn(&Value) -> bool,
) -> Value {
    let start = Instant::now();
    let mut last = None;
    loop {
        if let Some(v) = status(ns, l, s) {
            if cond(&v) {
                eprintln!("after {:.1} s: {what}", start.elapsed().as_secs_f64());
                return v;
            }
            last = Some(v);
        }
        if start.elapsed() > limit {
            let mut text = String::new();
            for name in ["learner.log", "selector.log", "actor0.log"] {
                let log = std::fs::read_to_string(logs.join(name)).unwrap_or_default();
                let tail: Vec<&str> = log.lines().rev().take(40).collect();
                text += &format!("--- {name} (last 40 lines)\n");
                for line in tail.iter().rev() {
                    text += line;
                    text += "\n";
                }
            }
            panic!("never within {limit:?}: {what}\nlast status: {last:?}\n{text}");
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// What the actor did about a link outage, as its log says.
#[derive(Debug, Clone, Copy)]
enum Outage {
    /// A transitions send timed out on a receiver that returned no credit.
    Dropped,
    /// Zenoh closed the session; the learner's token went with it and the actor paused.
    Paused,
}

fn outage_effect(line: &str) -> Option<Outage> {
    if line.contains("/transitions blocked") && line.contains("dropped and counted") {
        Some(Outage::Dropped)
    } else if line.contains("no learner receives transitions") {
        Some(Outage::Paused)
    } else {
        None
    }
}

fn read_lines(path: &Path) -> Vec<String> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .map(str::to_string)
        .collect()
}

/// The actor's own total of transition batches given up: the `dropped=N` of its newest
/// "dropped and counted" line on the transitions stream (0 without one).
fn logged_drops(path: &Path) -> u64 {
    read_lines(path)
        .iter()
        .filter(|l| l.contains("/transitions blocked") && l.contains("dropped and counted"))
        .filter_map(|l| {
            let at = l.find(" dropped=")? + " dropped=".len();
            l[at..].split_whitespace().next()?.parse().ok()
        })
        .max()
        .unwrap_or(0)
}

#[test]
fn actor_in_another_namespace_trains_over_zenoh_and_survives_a_link_outage() {
    let tag = format!(
        "{}{}",
        std::process::id() % 100_000,
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .subsec_micros()
            % 1000
    );
    let (ns_a, ns_b) = (format!("terl-a-{tag}"), format!("terl-b-{tag}"));
    let mut net = Net {
        namespaces: vec![],
        children: vec![],
    };
    // Without namespaces nothing here is exercised: fail rather than pass (the suite runs as
    // root, CI too).
    if let Err(e) = ip(&["netns", "add", &ns_a]) {
        panic!("network namespaces cannot be created here ({e}); needs root and `ip`");
    }
    net.namespaces.push(ns_a.clone());
    ip(&["netns", "add", &ns_b]).unwrap();
    net.namespaces.push(ns_b.clone());
    // veth names are at most 15 bytes.
    let (va, vb) = (format!("tza{tag}"), format!("tzb{tag}"));
    ip(&["link", "add", &va, "type", "veth", "peer", "name", &vb]).unwrap();
    ip(&["link", "set", &va, "netns", &ns_a]).unwrap();
    ip(&["link", "set", &vb, "netns", &ns_b]).unwrap();
    let octet = 1 + (std::process::id() % 250);
    let (addr_a, addr_b) = (format!("10.213.{octet}.1"), format!("10.213.{octet}.2"));
    for (ns, dev, addr) in [(&ns_a, &va, &addr_a), (&ns_b, &vb, &addr_b)] {
        ip(&["-n", ns, "addr", "add", &format!("{addr}/24"), "dev", dev]).unwrap();
        ip(&["-n", ns, "link", "set", dev, "up"]).unwrap();
        ip(&["-n", ns, "link", "set", "lo", "up"]).unwrap();
    }

    let bins = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let run_id = format!("netns-{tag}");
    let run_dir = dir.path().join(&run_id);
    std::fs::create_dir_all(&run_dir).unwrap();
    // The run's TLS files for the learner's namespace address (gRPC and Zenoh), and, for a
    // rogue, another run's.
    let certs = |dir: &str| -> String {
        let out = Command::new(env!("CARGO_BIN_EXE_terl"))
            .args(["certs", "--host", &addr_a, "--out"])
            .arg(run_dir.join(dir))
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        String::from_utf8(out.stdout)
            .unwrap()
            .replace("[cluster]\n", "")
    };
    let (tls_keys, other_tls_keys) = (certs("tls"), certs("other-tls"));
    CA.set(run_dir.join("tls/ca.pem")).unwrap();
    // The smoke cluster over Zenoh, giving up on a full receiver after 1 s so that an
    // outage of a few seconds is counted.
    let smoke =
        std::fs::read_to_string(workspace().join("deploy/configs/cluster-smoke.toml")).unwrap();
    assert!(smoke.contains("block_timeout_secs = 10\n"));
    let run_file = |tls: &str| {
        smoke
            .replace(
                "block_timeout_secs = 10\n",
                &format!("block_timeout_secs = 1\ntransport = \"zenoh\"\n{tls}\n"),
            )
            // A fast actor reaches the smoke run's 1M env steps within this test.
            .replace("[train]\n", "[train]\ntotal_env_steps = 1_000_000_000\n")
    };
    let config = run_dir.join("zenoh.toml");
    std::fs::write(&config, run_file(&tls_keys)).unwrap();
    let other_ca_config = run_dir.join("zenoh-other-ca.toml");
    std::fs::write(&other_ca_config, run_file(&other_tls_keys)).unwrap();
    let common = |extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = [
            "--config",
            &config.display().to_string(),
            "--run-id",
            &run_id,
            "--num-actors",
            "1",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run_dir_s = run_dir.display().to_string();
    let zenoh_learner = format!("quic/{addr_a}:7447");
    net.spawn(
        &ns_a,
        &bins.join("terl-learner"),
        &common(&[
            "--addr",
            &format!("{addr_a}:0"),
            "--run-dir",
            &run_dir_s,
            "--zenoh-listen",
            &zenoh_learner,
        ]),
        &run_dir.join("learner.log"),
    );
    let learner = wait_for_file(&run_dir.join("learner.addr"));
    net.spawn(
        &ns_a,
        &bins.join("terl-selector"),
        &common(&[
            "--addr",
            &format!("{addr_a}:0"),
            "--run-dir",
            &run_dir_s,
            "--learner-addr",
            &learner,
            "--zenoh-listen",
            &format!("quic/{addr_a}:7448"),
            "--zenoh-connect",
            &zenoh_learner,
        ]),
        &run_dir.join("selector.log"),
    );
    let selector = wait_for_file(&run_dir.join("selector.addr"));
    let actor_args = common(&[
        "--actor-id",
        "0",
        "--learner-addr",
        &learner,
        "--zenoh-connect",
        &zenoh_learner,
    ]);
    net.spawn(
        &ns_b,
        &bins.join("terl-actor"),
        &actor_args,
        &run_dir.join("actor0.log"),
    );

    // Transitions flow, weights arrive (the actor acts with a published version), episodes
    // reach the selector.
    let before = until(
        &ns_a,
        &learner,
        &selector,
        "the remote actor's transitions, made with published weights",
        Duration::from_secs(120),
        &run_dir,
        |v| {
            let l = &v["learner"];
            let a = l["actors"].as_array().and_then(|a| a.first().cloned());
            a.is_some_and(|a| u(&a, "env_steps") > 2_000 && u(&a, "policy_version") > 0)
                && u(&v["selector"], "episodes_seen") > 0
        },
    );

    // Status lists the actor with its host name and the address it reaches the learner from.
    let actor = &before["learner"]["actors"][0];
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap();
    assert_eq!(actor["host"].as_str(), Some(host.trim()), "{before}");
    let address = actor["address"].as_str().unwrap_or_default();
    assert!(
        address.starts_with(&format!("{addr_b}:")),
        "the actor's address {address:?} is not in its namespace ({addr_b})"
    );

    // The Zenoh data plane is locked with QUIC (TLS 1.3) and the run's token. An actor from another host
    // with a wrong token, or with the right token but another run's CA (it cannot trust the
    // learner's certificate), reaches no session of the run: it cannot check, so cannot claim,
    // an actor id, and stops naming the learner's endpoint. One with the right token and CA is
    // refused the id actor 0 holds, also from the learner's namespace, where actor 0 (listening
    // on its own loopback) cannot be reached: the learner answers with the claims it sees.
    let other_ca_args: Vec<String> = actor_args
        .iter()
        .map(|a| {
            if *a == config.display().to_string() {
                other_ca_config.display().to_string()
            } else {
                a.clone()
            }
        })
        .collect();
    for (token, name, ns, args) in [
        (
            "wrong-token-0123456789abcdefghij",
            "rogue",
            &ns_b,
            &actor_args,
        ),
        (TOKEN, "other-ca", &ns_b, &other_ca_args),
        (TOKEN, "second", &ns_a, &actor_args),
    ] {
        let log = run_dir.join(format!("actor-{name}.log"));
        let child = spawn_in(ns, &bins.join("terl-actor"), args, &log, token);
        let (exit, text) = exit_of(child, &log);
        eprintln!(
            "{name} actor: {exit}, {}",
            text.lines().last().unwrap_or_default()
        );
        assert!(!exit.success(), "the {name} actor ran:\n{text}");
        if name == "second" {
            assert!(text.contains("already streaming"), "{text}");
        } else {
            assert!(
                text.contains("timed out") && text.contains(&zenoh_learner),
                "{text}"
            );
            assert!(!text.contains("already streaming"), "{text}");
        }
    }
    let v = status(&ns_a, &learner, &selector).expect("the learner answers");
    assert_eq!(
        v["learner"]["actors"].as_array().map(Vec::len),
        Some(1),
        "{v}"
    );

    // The link goes down, and stays down until the actor has visibly given something up:
    // either a send on the transitions stream timed out on a receiver it got no credit back
    // from (dropped and counted), or the sender waited inside Zenoh's own queue until Zenoh
    // closed the session (5 s; the learner's token is gone, the actor pauses). A fixed-length
    // outage would let the actor ride it out inside Zenoh's queue with nothing lost, which is
    // correct but shows nothing. Then the link comes up again.
    let actor_log = run_dir.join("actor0.log");
    let lines_before = read_lines(&actor_log).len();
    ip(&["-n", &ns_b, "link", "set", &vb, "down"]).unwrap();
    let down = Instant::now();
    let gave_up = loop {
        std::thread::sleep(Duration::from_millis(200));
        let new: Vec<String> = read_lines(&actor_log).split_off(lines_before);
        if let Some(line) = new.iter().find(|l| outage_effect(l).is_some()) {
            break outage_effect(line).expect("found above");
        }
        assert!(
            down.elapsed() < Duration::from_secs(60),
            "60 s into the outage the actor neither dropped a transition batch nor noticed \
             the learner gone:\n{}",
            new.join("\n")
        );
    };
    // Long enough for a few more of whatever is happening.
    std::thread::sleep(Duration::from_secs(3));
    ip(&["-n", &ns_b, "link", "set", &vb, "up"]).unwrap();
    eprintln!(
        "link down {:.1} s; the actor {}",
        down.elapsed().as_secs_f64(),
        match gave_up {
            Outage::Dropped => "dropped transition batches",
            Outage::Paused => "paused for the learner",
        }
    );

    let steps_before = u(&before["learner"], "env_steps_total");
    let after = until(
        &ns_a,
        &learner,
        &selector,
        "transitions flowing again after the outage, with what the actor gave up reported",
        Duration::from_secs(180),
        &run_dir,
        |v| {
            let l = &v["learner"];
            // Every drop the actor logged during the outage reaches the learner, stamped on
            // the first message that gets through.
            u(l, "env_steps_total") > steps_before + 2_000
                && u(l, "transition_batches_dropped") >= logged_drops(&actor_log)
        },
    );
    let l = &after["learner"];
    let actor = &l["actors"][0];
    assert_eq!(
        u(actor, "transition_batches_dropped"),
        u(l, "transition_batches_dropped"),
        "{after}"
    );
    assert!(u(l, "transitions_dropped") >= u(l, "transition_batches_dropped"));
    let log = read_lines(&actor_log).join("\n");
    match gave_up {
        Outage::Dropped => assert!(logged_drops(&actor_log) > 0),
        Outage::Paused => assert!(
            log.contains("the learner is back; rejoining"),
            "the actor paused for the learner but never rejoined:\n{log}"
        ),
    }
    // Every process is still alive.
    for child in &mut net.children {
        assert!(child.try_wait().unwrap().is_none(), "a process died");
    }
    // Exactly what the actor counted, no more: its sink is the only place a batch is given up.
    // The actor's own total is its last line on a clean stop (the drop warnings do not cover
    // a send that found no receiver, which is counted too), so it is stopped now.
    let actor_pid = net.children[2].id();
    Command::new("kill")
        .args(["-TERM", &actor_pid.to_string()])
        .status()
        .unwrap();
    let start = Instant::now();
    let exit = loop {
        if let Some(status) = net.children[2].try_wait().unwrap() {
            break status;
        }
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the actor did not stop on SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(exit.success(), "the actor stopped with {exit}");
    let stopped = read_lines(&actor_log)
        .into_iter()
        .rev()
        .find(|l| l.contains("actor stopped"))
        .expect("the actor's last line");
    let own: u64 = stopped
        .split(" transition_batches_dropped=")
        .nth(1)
        .and_then(|t| t.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count in {stopped}"));
    let v = status(&ns_a, &learner, &selector).expect("the learner answers");
    assert_eq!(
        u(&v["learner"], "transition_batches_dropped"),
        own,
        "the learner reports what the actor counted: {stopped}\n{v}"
    );
    assert!(own > 0 || matches!(gave_up, Outage::Paused));
}
