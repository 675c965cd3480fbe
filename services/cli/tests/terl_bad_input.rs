//! TERL-mode services refuse bad input at start-up with a clear message and a non-zero exit:
//! a missing or foreign `--tep-dataset`, a selector without the learner's address, and a run
//! file with invalid `[ptr]`/`[tep]` sections.

use std::path::Path;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

mod common;

use common::{service_binaries, workspace};

/// Runs a service that must fail on its own within 60 s.
fn run_failing(bin: &Path, args: &[&str]) -> Output {
    let mut child = Command::new(bin)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("{} kept running on bad input", bin.display());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = child.wait_with_output().unwrap();
    assert!(
        !out.status.success(),
        "{} accepted bad input",
        bin.display()
    );
    out
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn args<'a>(config: &'a str, run_id: &'a str, run_dir: &'a str) -> Vec<&'a str> {
    vec![
        "--config",
        config,
        "--run-id",
        run_id,
        "--addr",
        "127.0.0.1:0",
        "--run-dir",
        run_dir,
    ]
}

#[test]
fn terl_services_refuse_bad_datasets_configs_and_missing_addresses() {
    let bins = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = workspace().join("deploy/configs/smoke-terl.toml");
    let config = config.to_str().unwrap();
    let run_dir = dir.path().join("run");
    let run_dir = run_dir.to_str().unwrap();
    let id = format!("bad-{}", std::process::id());

    // A dataset path that does not exist: named in the error.
    let missing = dir.path().join("nope.mcap");
    let mut a = args(config, &id, run_dir);
    a.extend(["--tep-dataset", missing.to_str().unwrap()]);
    let e = stderr(&run_failing(&bins.join("terl-learner"), &a));
    assert!(
        e.contains("cannot load the TEP dataset") && e.contains("nope.mcap"),
        "{e}"
    );

    // Not an MCAP file.
    let garbage = dir.path().join("garbage.mcap");
    std::fs::write(&garbage, b"this is not a dataset").unwrap();
    let mut a = args(config, &id, run_dir);
    a.extend(["--tep-dataset", garbage.to_str().unwrap()]);
    let e = stderr(&run_failing(&bins.join("terl-learner"), &a));
    assert!(e.contains("not an MCAP file"), "{e}");

    // A valid dataset of tasks this run does not train.
    let foreign = dir.path().join("foreign.mcap");
    let mut w = terl_telemetry::TepDatasetWriter::create(&foreign).unwrap();
    w.write(
        &terl_wire::TepSample {
            task: "door-open-v3".into(),
            trajectory_id: 1,
            step: 0,
            priority: 1.0,
            obs: [0.0; 39],
            next_obs: [0.0; 39],
            goal_obs: None,
            action: [0.0; 4],
            success: false,
            variation: None,
        },
        1,
    )
    .unwrap();
    w.finish().unwrap();
    let mut a = args(config, &id, run_dir);
    a.extend(["--tep-dataset", foreign.to_str().unwrap()]);
    let e = stderr(&run_failing(&bins.join("terl-learner"), &a));
    assert!(e.contains("has no sample of this run's tasks"), "{e}");

    // The selector cannot score without the learner's weights.
    let e = stderr(&run_failing(
        &bins.join("terl-selector"),
        &args(config, &id, run_dir),
    ));
    assert!(e.contains("--learner-addr"), "{e}");

    // Invalid [ptr] and [tep] values are named.
    let text = std::fs::read_to_string(config).unwrap();
    for (from, to, needle) in [
        ("top_fraction = 0.25", "top_fraction = 1.5", "top_fraction"),
        (
            "pool_trajectories = 2",
            "pool_trajectories = 0",
            "pool_trajectories",
        ),
        (
            "updates_per_sac_update = 0.1",
            "updates_per_sac_update = -1.0",
            "updates_per_sac_update",
        ),
        ("sigma = 0.98", "sigma = 2.0", "guidance.sigma"),
    ] {
        assert!(text.contains(from), "smoke-terl.toml changed: {from}");
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, text.replace(from, to)).unwrap();
        let e = stderr(&run_failing(
            &bins.join("terl-learner"),
            &args(bad.to_str().unwrap(), &id, run_dir),
        ));
        assert!(e.contains(needle), "{needle}: {e}");
    }
}

/// A log that cannot be written (stderr on `/dev/full`: every write fails with "No space left
/// on device", as a run folder's log on a full disk does) does not panic a service: the learner
/// and the selector start, serve, and stop on SIGTERM with code 0. (tracing reported a failed
/// log write with `eprint!`, which panicked on the same full stderr.)
#[test]
fn services_with_an_unwritable_log_run_and_stop_cleanly() {
    let bins = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = common::tiny_run_file(dir.path());
    let run_dir = dir.path().join("run");
    let run_id = format!("full-log-{}", std::process::id());
    for service in ["terl-learner", "terl-selector"] {
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .expect("/dev/full");
        let mut child = Command::new(bins.join(service))
            .args(args(
                config.to_str().unwrap(),
                &run_id,
                run_dir.to_str().unwrap(),
            ))
            // Every log line at debug level: many failed writes.
            .env("RUST_LOG", "debug")
            .stdout(std::process::Stdio::null())
            .stderr(full)
            .spawn()
            .unwrap();
        let role = service.trim_start_matches("terl-");
        let addr_file = run_dir.join(format!("{role}.addr"));
        common::wait_for_addr(&addr_file, Some(&mut child), Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(500));
        Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status()
            .unwrap();
        let status = child.wait().unwrap();
        assert_eq!(
            status.code(),
            Some(0),
            "{service} with a full log: {status}"
        );
    }
}

/// A run has one learner: a second `terl-learner` of a live run (same run id and folder) is
/// refused by the run's streams before it writes its address, so `learner.addr` keeps naming
/// the live learner (which `terl status` and the actors read) and the live learner goes on.
#[test]
fn a_second_learner_of_a_run_is_refused_and_leaves_the_first_one_s_address() {
    let bins = service_binaries();
    let dir = tempfile::tempdir().unwrap();
    let config = common::tiny_run_file(dir.path());
    let run_dir = dir.path().join("run");
    let run_id = format!("two-learners-{}", std::process::id());
    let a = args(config.to_str().unwrap(), &run_id, run_dir.to_str().unwrap());
    let mut first = Command::new(bins.join("terl-learner"))
        .args(&a)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let addr_file = run_dir.join("learner.addr");
    common::wait_for_addr(&addr_file, Some(&mut first), Duration::from_secs(60));
    let live = std::fs::read_to_string(&addr_file).unwrap();
    let e = stderr(&run_failing(&bins.join("terl-learner"), &a));
    assert!(e.contains("a run has one learner"), "{e}");
    assert_eq!(
        std::fs::read_to_string(&addr_file).unwrap(),
        live,
        "the refused learner replaced the live learner's address"
    );
    assert!(
        first.try_wait().unwrap().is_none(),
        "the live learner stopped"
    );
    Command::new("kill")
        .args(["-TERM", &first.id().to_string()])
        .status()
        .unwrap();
    assert_eq!(first.wait().unwrap().code(), Some(0));
}

/// The Zenoh data plane is locked like gRPC. `terl zenoh-router` listening beyond loopback
/// refuses to start over plain TCP (naming the `quic/` endpoint to write), over Zenoh's TLS link
/// (naming its upstream bug), over QUIC without the run's token (naming TERL_TOKEN) and over
/// QUIC without a certificate (naming --tls-cert). With them, over QUIC on loopback, a session
/// holding the token and the CA joins, one without the
/// token or without the CA is refused, and even at `RUST_LOG=trace` (Zenoh logs a session's
/// configuration at debug level) the token appears in no line of the router's log.
#[test]
fn a_zenoh_router_beyond_loopback_needs_quic_and_the_token_and_never_logs_it() {
    let terl = Path::new(env!("CARGO_BIN_EXE_terl"));
    let certs = tempfile::tempdir().unwrap();
    let made = Command::new(terl)
        .args(["certs", "--out"])
        .arg(certs.path())
        .output()
        .unwrap();
    assert!(made.status.success(), "{}", stderr(&made));
    let file = |name: &str| certs.path().join(name).display().to_string();
    let tls_flags = [
        "--tls-cert",
        &file("cert.pem"),
        "--tls-key",
        &file("key.pem"),
    ];
    for (listen, token, with_tls, expected) in [
        (
            "tcp/0.0.0.0:0",
            Some("router-test-token-0123456789abcdef"),
            true,
            "quic/0.0.0.0:0",
        ),
        (
            "tls/0.0.0.0:0",
            Some("router-test-token-0123456789abcdef"),
            true,
            "#2557",
        ),
        ("quic/0.0.0.0:0", None, true, "TERL_TOKEN"),
        (
            "quic/0.0.0.0:0",
            Some("router-test-token-0123456789abcdef"),
            false,
            "--tls-cert",
        ),
    ] {
        let mut cmd = Command::new(terl);
        cmd.args(["zenoh-router", "--listen", listen]);
        if with_tls {
            cmd.args(tls_flags);
        }
        match token {
            Some(t) => cmd.env("TERL_TOKEN", t),
            None => cmd.env_remove("TERL_TOKEN"),
        };
        let out = cmd.output().unwrap();
        assert_eq!(out.status.code(), Some(1), "{listen}");
        let err = stderr(&out);
        assert!(err.contains(listen) && err.contains(expected), "{err}");
    }

    // A missing token file is named, and its OS error said once (the message quotes it and
    // it is the message's source too).
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no-token");
    let out = Command::new(terl)
        .args(["zenoh-router", "--token-file"])
        .arg(&missing)
        .env_remove("TERL_TOKEN")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = stderr(&out);
    assert!(err.contains(&missing.display().to_string()), "{err}");
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");

    let token = "router-test-token-0123456789abcdef";
    // A field filter makes a directive more specific than any cap added as a directive.
    for rust_log in ["trace", "zenoh::api::session[{message}]=debug,trace"] {
        router_keeps_the_token_out_of_its_log(terl, token, rust_log, certs.path());
    }
}

fn router_keeps_the_token_out_of_its_log(terl: &Path, token: &str, rust_log: &str, certs: &Path) {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("quic/127.0.0.1:{port}");
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("router.log");
    let mut router = Command::new(terl)
        .args([
            "zenoh-router",
            "--listen",
            &endpoint,
            "--run-id",
            "router-test",
        ])
        .arg("--tls-cert")
        .arg(certs.join("cert.pem"))
        .arg("--tls-key")
        .arg(certs.join("key.pem"))
        .env("TERL_TOKEN", token)
        .env("RUST_LOG", rust_log)
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !std::fs::read_to_string(&log)
        .unwrap_or_default()
        .contains("listening on")
    {
        assert!(router.try_wait().unwrap().is_none(), "the router exited");
        assert!(start.elapsed() < Duration::from_secs(30), "no router");
        std::thread::sleep(Duration::from_millis(50));
    }
    let client = |secret: Option<&str>, ca: &Path| {
        terl_transport::ZenohTransport::open(
            terl_transport::TransportConfig {
                zenoh: terl_transport::ZenohConfig {
                    mode: terl_transport::ZenohMode::Client,
                    connect: vec![endpoint.clone()],
                    secret: secret.map(|s| terl_transport::ZenohSecret::new(s).unwrap()),
                    tls: terl_transport::ZenohTls {
                        ca: Some(ca.to_path_buf()),
                        ..Default::default()
                    },
                    ..Default::default()
                },
                ..terl_transport::TransportConfig::new("router-test", 1)
            },
            "test",
        )
    };
    // Another run's CA: the router's certificate is not trusted.
    let other = tempfile::tempdir().unwrap();
    let made = Command::new(terl)
        .args(["certs", "--out"])
        .arg(other.path())
        .output()
        .unwrap();
    assert!(made.status.success());
    let (ca, other_ca) = (certs.join("ca.pem"), other.path().join("ca.pem"));
    // A client fails to open when it reaches no router that lets it in.
    assert!(
        client(Some(token), &ca).is_ok(),
        "the token holder is refused"
    );
    // Each refusal names what to check (Zenoh's own message is "Unable to connect").
    let refused =
        |result: Result<terl_transport::ZenohTransport, terl_transport::TransportError>,
         names: &str| {
            let Err(err) = result else {
                panic!("a client got in")
            };
            let err = err.to_string();
            assert!(err.contains(names) && err.contains(&endpoint), "{err}");
        };
    refused(client(None, &ca), "this process has no token");
    refused(
        client(Some("another-token-0123456789"), &ca),
        "is the listener's",
    );
    refused(client(Some(token), &other_ca), "[cluster] tls_ca");
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(router.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    assert!(router.wait().unwrap().success());
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(
        text.contains("sessions authenticate with the run's token"),
        "{text}"
    );
    // Logging was on at trace level, Zenoh's own lines included.
    assert!(
        text.lines()
            .any(|l| l.contains("TRACE") && l.contains("zenoh")),
        "no trace lines: {}",
        &text[..text.len().min(2000)]
    );
    assert!(
        !text.contains(token),
        "RUST_LOG={rust_log}: the token is in the log"
    );
}
