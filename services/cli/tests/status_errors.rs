//! `terl status` says what went wrong in words a user can act on, against real sockets on
//! 127.0.0.1: nothing listening (the cause once, not "transport error: transport error"), a
//! server that closes the connection at once (what a TLS server does to a plaintext client:
//! the hint names the CA setting), and a real `terl-learner` with a token asked without one
//! (refused, not "nothing answers").

use std::net::TcpListener;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

mod common;

use common::service_binaries;

fn status(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_terl"))
        .arg("status")
        .args(args)
        .current_dir(dir)
        .env_remove("TERL_TOKEN")
        .output()
        .unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A port nobody listens on: bound, its number read, then closed.
fn closed_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

#[test]
fn nothing_listening_names_the_cause_once() {
    let dir = tempfile::tempdir().unwrap();
    let addr = format!("127.0.0.1:{}", closed_port());
    let out = status(
        &["--addr", &addr, "--selector-addr", &addr, "--timeout", "5"],
        dir.path(),
    );
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("Connection refused"), "{err}");
    for repeated in [
        "transport error: transport error",
        "tcp connect error: tcp connect error",
    ] {
        assert!(!err.contains(repeated), "{repeated:?} in {err}");
    }
}

#[test]
fn a_server_that_closes_at_once_gets_the_tls_hint() {
    let dir = tempfile::tempdir().unwrap();
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    // Accepts every connection and closes it without a byte, as a TLS server does when a
    // plaintext client's first bytes are not a TLS handshake.
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            drop(stream);
        }
    });
    let out = status(
        &["--addr", &addr, "--selector-addr", &addr, "--timeout", "5"],
        dir.path(),
    );
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("cluster.tls_ca"), "{err}");
}

#[test]
fn a_learner_with_a_token_asked_without_one_is_refused_by_name() {
    let bin = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = common::tiny_run_file(dir.path());
    let run_dir = dir.path().join("run");
    let run_id = format!("status-token-{}", std::process::id());
    let mut learner = Command::new(bin.join("terl-learner"))
        .args(["--config", config.to_str().unwrap(), "--run-id", &run_id])
        .args([
            "--addr",
            "127.0.0.1:0",
            "--run-dir",
            run_dir.to_str().unwrap(),
        ])
        .env("TERL_TOKEN", "a-token-the-client-does-not-have")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let addr_file = run_dir.join("learner.addr");
    let addr = common::wait_for_addr(&addr_file, Some(&mut learner), Duration::from_secs(60));
    let out = status(&["--addr", &addr, "--timeout", "5"], dir.path());
    let _ = Command::new("kill")
        .args(["-TERM", &learner.id().to_string()])
        .status();
    let _ = learner.wait();
    let err = stderr(&out);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("refused this client's token"), "{err}");
    assert!(!err.contains("nothing answers"), "{err}");
}

#[test]
fn an_address_file_that_is_a_fifo_or_not_text_is_an_error_not_a_hang() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("runs/r1");
    std::fs::create_dir_all(&run).unwrap();
    assert!(Command::new("mkfifo")
        .arg(run.join("learner.addr"))
        .status()
        .unwrap()
        .success());
    let out = Command::new("timeout")
        .arg("60")
        .arg(env!("CARGO_BIN_EXE_terl"))
        .args(["status", "--run"])
        .arg(&run)
        .env_remove("TERL_TOKEN")
        .output()
        .unwrap();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("not an address file"), "{err}");
    std::fs::remove_file(run.join("learner.addr")).unwrap();
    std::fs::write(run.join("learner.addr"), b"\xff\xfe\x00").unwrap();
    let out = status(&["--run", run.to_str().unwrap()], dir.path());
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("not text"), "{err}");
}

/// A stopped launcher run's address files stay behind; when another run's learner now serves at
/// that address, `terl status --run` of the stopped run says so instead of showing the other.
#[test]
fn a_stopped_runs_address_served_by_another_run_is_named_not_shown() {
    let bin = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = common::tiny_run_file(dir.path());
    let live_dir = dir.path().join("runs/now-running");
    let mut learner = Command::new(bin.join("terl-learner"))
        .args([
            "--config",
            config.to_str().unwrap(),
            "--run-id",
            "now-running",
        ])
        .args([
            "--addr",
            "127.0.0.1:0",
            "--run-dir",
            live_dir.to_str().unwrap(),
        ])
        .env_remove("TERL_TOKEN")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let addr = common::wait_for_addr(
        &live_dir.join("learner.addr"),
        Some(&mut learner),
        Duration::from_secs(60),
    );
    // The stopped run: a launcher's folder whose learner.addr now points at the live learner.
    let stopped = dir.path().join("runs/stopped-run");
    std::fs::create_dir_all(&stopped).unwrap();
    std::fs::write(stopped.join("cluster.txt"), "run_id=stopped-run\n").unwrap();
    std::fs::write(stopped.join("learner.addr"), &addr).unwrap();
    std::fs::write(stopped.join("selector.addr"), &addr).unwrap();
    let out = status(
        &["--run", stopped.to_str().unwrap(), "--timeout", "5"],
        dir.path(),
    );
    let _ = Command::new("kill")
        .args(["-TERM", &learner.id().to_string()])
        .status();
    let _ = learner.wait();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("serves run now-running, not stopped-run"),
        "{err}"
    );
}
