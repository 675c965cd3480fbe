//! `terl bench transport --transport zenoh --netns` cleans up after itself on every exit
//! path: a namespace left by a bench that was killed (SIGKILL) is removed by the next one, and
//! a bench stopped by SIGTERM removes its own namespace and veth before exiting. Needs root
//! (`ip netns`); skips with a message where namespaces cannot be created.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| e.to_string())?;
    if out.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).trim().to_string())
    }
}

fn namespaces() -> String {
    let out = Command::new("ip").args(["netns", "list"]).output().unwrap();
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn has_namespace(name: &str) -> bool {
    namespaces()
        .lines()
        .any(|l| l.split_whitespace().next() == Some(name))
}

fn has_link(dev: &str) -> bool {
    Command::new("ip")
        .args(["link", "show", dev])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Removes the namespace and veth of a fake killed bench if the test fails half-way.
struct Leftover(&'static str, &'static str);

impl Drop for Leftover {
    fn drop(&mut self) {
        let _ = ip(&["link", "del", self.1]);
        let _ = ip(&["netns", "del", self.0]);
    }
}

#[test]
fn netns_bench_removes_stale_namespaces_and_its_own_on_sigterm() {
    // A bench killed with SIGKILL: its process id is above any pid_max, so it no longer runs.
    const STALE: &str = "terl-bench-999999999";
    const STALE_DEV: &str = "tbh999999";
    // Without namespaces nothing here is exercised: fail rather than pass (the suite runs as
    // root, CI too).
    if let Err(e) = ip(&["netns", "add", STALE]) {
        panic!("network namespaces cannot be created here ({e}); needs root and `ip`");
    }
    let _leftover = Leftover(STALE, STALE_DEV);
    ip(&[
        "link",
        "add",
        STALE_DEV,
        "type",
        "veth",
        "peer",
        "name",
        "tbn999999",
    ])
    .unwrap();
    ip(&["link", "set", "tbn999999", "netns", STALE]).unwrap();
    assert!(has_namespace(STALE) && has_link(STALE_DEV));

    let mut bench = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args([
            "bench",
            "transport",
            "--transport",
            "zenoh",
            "--netns",
            "--seconds",
            "3",
            "--publishers",
            "1",
            "--versions",
            "2",
            "--subscribers",
            "1",
            "--json",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = bench.id();
    let (own, own_dev) = (
        format!("terl-bench-{pid}"),
        format!("tbh{}", pid % 1_000_000),
    );
    let deadline = Instant::now() + Duration::from_secs(120);
    // Set up completely: the last step of the set-up brings the namespace's loopback up.
    let ready = || {
        Command::new("ip")
            .args(["-n", &own, "-o", "link", "show", "lo"])
            .output()
            .is_ok_and(|o| String::from_utf8_lossy(&o.stdout).contains(",UP"))
    };
    while !ready() {
        if let Some(status) = bench.try_wait().unwrap() {
            let mut err = String::new();
            let _ = std::io::Read::read_to_string(bench.stderr.as_mut().unwrap(), &mut err);
            panic!("the bench ended ({status}) before creating its namespace:\n{err}");
        }
        assert!(Instant::now() < deadline, "no namespace {own} within 120 s");
        std::thread::sleep(Duration::from_millis(20));
    }
    // The stale namespace and veth were removed before the bench made its own.
    assert!(
        !has_namespace(STALE),
        "{STALE} left in place:\n{}",
        namespaces()
    );
    assert!(!has_link(STALE_DEV), "{STALE_DEV} left in place");

    let kill = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let out = bench.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(143), "{stderr}");
    assert!(
        !has_namespace(&own),
        "{own} left after SIGTERM:\n{}",
        namespaces()
    );
    assert!(!has_link(&own_dev), "{own_dev} left after SIGTERM");
    assert!(
        stderr.contains(&format!("removed the network namespace {own}")),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("removed network namespace {STALE}")),
        "{stderr}"
    );
}
