//! The container image's runtime stage is the folder `deploy/container/stage.sh` assembles
//! (binaries, libmujoco from the MuJoCo wheel, Meta-World assets, run files, env.sh). This
//! test stages into a temporary folder and runs the staged `terl` from elsewhere with only
//! env.sh's settings: a Python Meta-World trace replays through the staged library and assets
//! within the parity tolerances. With the assets variable pointed at an empty folder the same
//! replay fails, so it is the staged copy that was used.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

mod common;

use common::{service_binaries, workspace};

fn staged(dest: &Path, script: &str) -> std::process::Output {
    Command::new("bash")
        .arg("-c")
        .arg(format!("source {}/env.sh && {script}", dest.display()))
        .current_dir(dest)
        .env_remove("TERL_MUJOCO_LIB")
        .env_remove("TERL_METAWORLD_ASSETS")
        .output()
        .unwrap()
}

#[test]
fn staged_runtime_folder_replays_a_python_trace_from_its_own_library_and_assets() {
    let bins = service_binaries();
    let root = workspace();
    let dir = tempfile::tempdir().unwrap();
    let dest = dir.path().join("opt-terl");
    let out = Command::new(root.join("deploy/container/stage.sh"))
        .args(["--bin-dir", bins.to_str().unwrap(), dest.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "stage.sh failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "bin/terl",
        "bin/terl-learner",
        "bin/terl-selector",
        "bin/terl-actor",
        "lib/libmujoco.so",
        "assets/metaworld/sawyer_xyz/sawyer_reach_v3.xml",
        "configs/mt10.toml",
    ] {
        assert!(dest.join(f).exists(), "{f} not staged");
    }

    let trace = root.join("tests/fixtures/metaworld/pick-place-v3-s1.jsonl.gz");
    let replay = format!(
        "terl env replay --trace {} --out rust.jsonl && terl env compare {} rust.jsonl",
        trace.display(),
        trace.display()
    );
    let ok = staged(&dest, &replay);
    assert!(
        ok.status.success(),
        "staged replay failed: {}{}",
        String::from_utf8_lossy(&ok.stdout),
        String::from_utf8_lossy(&ok.stderr)
    );
    // The staged binaries find the library and assets through env.sh: break the assets
    // path and the replay fails, naming it.
    std::fs::create_dir_all(dest.join("empty")).unwrap();
    let broken = staged(&dest, &format!("TERL_METAWORLD_ASSETS=$PWD/empty {replay}"));
    assert!(!broken.status.success(), "replay worked without assets");
    assert!(
        String::from_utf8_lossy(&broken.stderr).contains("empty"),
        "{}",
        String::from_utf8_lossy(&broken.stderr)
    );
}

/// Containers, networks and images one test made; removed on drop, also on failure.
struct Podman {
    containers: Vec<String>,
    networks: Vec<String>,
    images: Vec<String>,
}

/// `deploy/container/podman.sh ARGS`: podman with terl's settings (containers.conf).
fn podman(args: &[&str]) -> std::process::Output {
    Command::new(workspace().join("deploy/container/podman.sh"))
        .args(args)
        .output()
        .expect("deploy/container/podman.sh runs")
}

/// [`podman`] that must succeed; returns its stdout.
fn podman_ok(args: &[&str]) -> String {
    let out = podman(args);
    assert!(
        out.status.success(),
        "podman {} failed: {}{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

impl Drop for Podman {
    fn drop(&mut self) {
        for c in &self.containers {
            let _ = podman(&["rm", "-f", "-t", "0", c]);
        }
        for n in &self.networks {
            let _ = podman(&["network", "rm", "-f", n]);
        }
        for i in &self.images {
            let _ = podman(&["rmi", "-f", i]);
        }
    }
}

impl Podman {
    /// `podman run -d --name NAME ARGS`, remembered for removal.
    fn run_detached(&mut self, name: &str, args: &[&str]) {
        let mut all = vec!["run", "-d", "--name", name];
        all.extend_from_slice(args);
        self.containers.push(name.to_string());
        podman_ok(&all);
    }

    /// The container's output so far (for failure messages).
    fn logs(&self) -> String {
        self.containers
            .iter()
            .map(|c| {
                let out = podman(&["logs", "--tail", "30", c]);
                format!(
                    "--- {c}\n{}{}",
                    String::from_utf8_lossy(&out.stdout),
                    String::from_utf8_lossy(&out.stderr)
                )
            })
            .collect()
    }

    /// SIGTERM (`podman stop`, up to 60 s before SIGKILL), then the container's exit code.
    fn stop(&self, name: &str) -> i64 {
        podman_ok(&["stop", "-t", "60", name]);
        podman_ok(&["inspect", "--format", "{{.State.ExitCode}}", name])
            .parse()
            .unwrap()
    }
}

/// Polls `check` every 500 ms for up to `limit`; panics with `what` and the containers' logs.
fn wait_until(pods: &Podman, what: &str, limit: Duration, mut check: impl FnMut() -> bool) {
    let start = Instant::now();
    while !check() {
        assert!(
            start.elapsed() < limit,
            "never within {limit:?}: {what}\n{}",
            pods.logs()
        );
        std::thread::sleep(Duration::from_millis(500));
    }
    eprintln!("after {:.1} s: {what}", start.elapsed().as_secs_f64());
}

/// The `terl status --json` output `status` must answer with the learner past
/// `env_steps` env steps, some updates, and an actor acting on published weights.
fn trained(status: &std::process::Output, env_steps: u64) -> bool {
    if !status.status.success() {
        return false;
    }
    let Ok(v) = serde_json::from_slice::<serde_json::Value>(&status.stdout) else {
        return false;
    };
    let l = &v["learner"];
    let actor_version = l["actors"][0]["policy_version"].as_u64().unwrap_or(0);
    l["env_steps_total"].as_u64().unwrap_or(0) > env_steps
        && l["updates"].as_u64().unwrap_or(0) > 0
        && actor_version > 0
}

/// A host folder the image's user (uid 10001) can write, mounted at `/runs`.
fn runs_volume(dir: &Path) -> String {
    let runs = dir.join("runs");
    std::fs::create_dir_all(&runs).unwrap();
    let out = Command::new("chown")
        .args(["10001:10001", runs.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "chown: {out:?}");
    format!("{}:/runs", runs.display())
}

/// The container image, built and run for real (issue: the image had never been built). The
/// runtime image is built with podman from the staged binaries on a Debian base made from
/// Debian packages (deploy/container/build.sh; no image registry needed), then:
///
/// 1. inside it, `terl env replay` of a Python Meta-World trace matches the trace;
/// 2. `terl cluster up` on the smoke run file, learner, selector and actor in one container over
///    shared memory, trains (status answers from inside), and `podman stop` (SIGTERM to the
///    launcher as PID 1) stops it: every service exits 0, the learner with a final checkpoint,
///    and the launcher exits by the signal (143);
/// 3. learner, selector and actor in three containers on a podman network, transitions and
///    episodes over Zenoh, weights and status over gRPC with a token, trains (status answers
///    from the host), and SIGTERM stops the learner with exit code 0 and a final checkpoint.
///
/// Needs root, podman, runc and debootstrap (`./deploy/setup.sh --container`, which
/// `./deploy/test.sh` runs).
#[test]
fn container_image_replays_a_trace_and_trains_over_shared_memory_and_zenoh() {
    let bins = service_binaries();
    let root = workspace();
    let tag = format!("{}", std::process::id());
    let image = format!("localhost/terl:test-{tag}");
    let mut pods = Podman {
        containers: vec![],
        networks: vec![],
        images: vec![image.clone()],
    };
    let build = Command::new(root.join("deploy/container/build.sh"))
        .args(["--staged", "--bin-dir", bins.to_str().unwrap()])
        .args(["--tag", &image])
        .output()
        .unwrap();
    assert!(
        build.status.success(),
        "deploy/container/build.sh failed (./deploy/setup.sh --container installs podman, runc \
         and debootstrap; the base image needs root): {}",
        String::from_utf8_lossy(&build.stderr)
    );
    eprintln!("{}", String::from_utf8_lossy(&build.stderr).trim());

    // 1. A Python trace replays inside the image, from the image's own library and assets.
    let fixtures = root.join("tests/fixtures/metaworld");
    let mount = format!("{}:/fixtures:ro", fixtures.display());
    let replay = podman(&[
        "run",
        "--rm",
        "--network=none",
        "-v",
        &mount,
        &image,
        "sh",
        "-c",
        "terl env replay --trace /fixtures/pick-place-v3-s1.jsonl.gz --out /tmp/rust.jsonl \
         && terl env compare /fixtures/pick-place-v3-s1.jsonl.gz /tmp/rust.jsonl",
    ]);
    assert!(
        replay.status.success(),
        "the replay in the container failed: {}{}",
        String::from_utf8_lossy(&replay.stdout),
        String::from_utf8_lossy(&replay.stderr)
    );

    let dir = tempfile::tempdir().unwrap();
    let volume = runs_volume(dir.path());
    cluster_in_one_container(&mut pods, &image, &tag, dir.path(), &volume);
    cluster_across_containers(&mut pods, &image, &tag, dir.path(), &volume);
}

/// `terl cluster up` in one container (the launcher as PID 1, shared memory between its
/// processes) trains and stops on SIGTERM: its services exit 0, a final checkpoint is written.
fn cluster_in_one_container(pods: &mut Podman, image: &str, tag: &str, dir: &Path, volume: &str) {
    // 2. One container, the launcher as PID 1, shared memory between its processes.
    let shm = format!("terl-shm-{tag}");
    let run_id = format!("container-shm-{tag}");
    pods.run_detached(
        &shm,
        &[
            "--network=none",
            "--shm-size=256m",
            "-v",
            volume,
            image,
            "terl",
            "cluster",
            "up",
            "--config",
            "/opt/terl/configs/cluster-smoke.toml",
            "--actors",
            "1",
            "--run-id",
            &run_id,
            "--runs-root",
            "/runs",
        ],
    );
    let run_dir = dir.join("runs").join(&run_id);
    wait_until(
        pods,
        "the one-container cluster trains",
        Duration::from_secs(180),
        || {
            let (Ok(l), Ok(s)) = (
                std::fs::read_to_string(run_dir.join("learner.addr")),
                std::fs::read_to_string(run_dir.join("selector.addr")),
            ) else {
                return false;
            };
            let status = podman(&[
                "exec",
                &shm,
                "terl",
                "status",
                "--json",
                "--addr",
                l.trim(),
                "--selector-addr",
                s.trim(),
            ]);
            trained(&status, 2_000)
        },
    );
    // The launcher stops its processes and then exits by the signal it got (128 + 15), as a
    // shell does; its services all exited 0.
    assert_eq!(
        pods.stop(&shm),
        143,
        "the launcher's exit code\n{}",
        pods.logs()
    );
    let out = podman(&["logs", &shm]);
    let log =
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
    assert!(
        log.contains("stopped: interrupted (signal 15) (worst exit code 0"),
        "{log}"
    );
    assert!(
        run_dir.join("checkpoints/final.safetensors").is_file(),
        "no final checkpoint after SIGTERM\n{}",
        pods.logs()
    );
}

/// Learner, selector and actor in three containers on a podman network: transitions and
/// episodes over Zenoh (QUIC), weights and status over gRPC (TLS), both with a token; `terl status` answers from the host; SIGTERM stops each with
/// exit code 0, the learner with a final checkpoint.
fn cluster_across_containers(pods: &mut Podman, image: &str, tag: &str, dir: &Path, volume: &str) {
    let net = format!("terl-net-{tag}");
    let pid = std::process::id();
    let prefix = format!("10.{}.{}", 200 + pid % 50, (pid / 50) % 250);
    let subnet = format!("{prefix}.0/24");
    pods.networks.push(net.clone());
    podman_ok(&["network", "create", "--subnet", &subnet, &net]);
    let (learner_ip, selector_ip, actor_ip) = (
        format!("{prefix}.2"),
        format!("{prefix}.3"),
        format!("{prefix}.4"),
    );
    let token = "container-test-token-0123456789abcdef";
    let token_env = format!("TERL_TOKEN={token}");
    let run_id = format!("container-zenoh-{tag}");
    let run_dir = format!("/runs/{run_id}");
    // The run's TLS files for the learner's and selector's addresses (gRPC and Zenoh), made
    // on the host with `terl certs`, readable by the image's user.
    let made = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args([
            "certs",
            "--host",
            &learner_ip,
            "--host",
            &selector_ip,
            "--out",
        ])
        .arg(dir.join("runs/tls"))
        .output()
        .unwrap();
    assert!(made.status.success(), "{made:?}");
    let out = Command::new("chown")
        .args(["-R", "10001:10001"])
        .arg(dir.join("runs/tls"))
        .output()
        .unwrap();
    assert!(out.status.success(), "chown: {out:?}");
    let smoke = std::fs::read_to_string(workspace().join("deploy/configs/cluster-smoke.toml"))
        .unwrap()
        .replace(
            "block_timeout_secs = 10\n",
            "block_timeout_secs = 10\ntransport = \"zenoh\"\ntls_ca = \"/runs/tls/ca.pem\"\n\
             tls_cert = \"/runs/tls/cert.pem\"\ntls_key = \"/runs/tls/key.pem\"\n",
        );
    std::fs::write(dir.join("runs/zenoh.toml"), smoke).unwrap();
    let zenoh_learner = format!("quic/{learner_ip}:7447");
    let learner_addr = format!("{learner_ip}:50051");
    let selector_addr = format!("{selector_ip}:50052");
    let service = |name: &str, ip: &str, bin: &str, extra: &[&str]| -> Vec<String> {
        let mut v: Vec<String> = [
            "--network",
            net.as_str(),
            "--ip",
            ip,
            "--shm-size=256m",
            "-e",
            token_env.as_str(),
            "-v",
            volume,
            "--hostname",
            name,
            image,
            bin,
            "--config",
            "/runs/zenoh.toml",
            "--run-id",
            run_id.as_str(),
            "--num-actors",
            "1",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let names = [
        format!("terl-learner-{tag}"),
        format!("terl-selector-{tag}"),
        format!("terl-actor-{tag}"),
    ];
    let learner_args = service(
        &names[0],
        &learner_ip,
        "terl-learner",
        &[
            "--addr",
            &learner_addr,
            "--run-dir",
            &run_dir,
            "--zenoh-listen",
            &zenoh_learner,
        ],
    );
    let selector_args = service(
        &names[1],
        &selector_ip,
        "terl-selector",
        &[
            "--addr",
            &selector_addr,
            "--run-dir",
            &run_dir,
            "--learner-addr",
            &learner_addr,
            "--zenoh-listen",
            &format!("quic/{selector_ip}:7448"),
            "--zenoh-connect",
            &zenoh_learner,
        ],
    );
    let actor_args = service(
        &names[2],
        &actor_ip,
        "terl-actor",
        &[
            "--actor-id",
            "0",
            "--learner-addr",
            &learner_addr,
            "--zenoh-connect",
            &zenoh_learner,
        ],
    );
    for (name, args) in names
        .iter()
        .zip([&learner_args, &selector_args, &actor_args])
    {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        pods.run_detached(name, &args);
    }
    wait_until(
        pods,
        "the three-container cluster trains over Zenoh (status asked from the host)",
        Duration::from_secs(180),
        || {
            let status = Command::new(env!("CARGO_BIN_EXE_terl"))
                .env("TERL_TOKEN", token)
                .args(["status", "--json", "--timeout", "5"])
                .args(["--addr", &learner_addr, "--selector-addr", &selector_addr])
                .arg("--tls-ca")
                .arg(dir.join("runs/tls/ca.pem"))
                .output()
                .unwrap();
            trained(&status, 2_000)
        },
    );
    for name in &names[1..] {
        assert_eq!(pods.stop(name), 0, "{name}'s exit code\n{}", pods.logs());
    }
    assert_eq!(
        pods.stop(&names[0]),
        0,
        "the learner's exit code\n{}",
        pods.logs()
    );
    assert!(
        dir.join("runs")
            .join(&run_id)
            .join("checkpoints/final.safetensors")
            .is_file(),
        "no final checkpoint after SIGTERM\n{}",
        pods.logs()
    );
}
