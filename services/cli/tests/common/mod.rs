//! What the process-level tests share: the workspace root and the service binaries.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The service binaries live next to `terl`; build them with the same profile (a no-op when
/// they are fresh), since cargo only builds this package's own binaries for its tests.
pub fn service_binaries() -> PathBuf {
    let bin_dir = Path::new(env!("CARGO_BIN_EXE_terl"))
        .parent()
        .expect("target dir")
        .to_path_buf();
    let profile = match bin_dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") => "dev".to_string(),
        Some(other) => other.to_string(),
        None => "dev".to_string(),
    };
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut build = Command::new(cargo);
    // The variables cargo sets for this test (CARGO_MANIFEST_DIR, CARGO_PKG_*, OUT_DIR, …)
    // would reach build scripts that watch them (ring's does) and rebuild their crates here
    // and again in the next ordinary build.
    for (name, _) in std::env::vars_os() {
        let Some(name) = name.to_str() else { continue };
        let set_by_cargo_for_tests = name == "OUT_DIR"
            || name == "CARGO_MANIFEST_DIR"
            || name == "CARGO_MANIFEST_PATH"
            || name == "CARGO_CRATE_NAME"
            || name == "CARGO_PRIMARY_PACKAGE"
            || name == "CARGO_TARGET_TMPDIR"
            || name.starts_with("CARGO_PKG_")
            || name.starts_with("CARGO_BIN_EXE_");
        if set_by_cargo_for_tests {
            build.env_remove(name);
        }
    }
    let status = build
        .current_dir(workspace())
        .args(["build", "-q", "--profile", &profile])
        // terl-cli too: its dependencies (plotters, image) turn on features of shared crates
        // (bytemuck, num-traits), and without it this build would differ from the workspace's
        // test build and rebuild half the dependency tree each time the two alternate.
        .args([
            "-p",
            "terl-cli",
            "-p",
            "terl-learner",
            "-p",
            "terl-actor",
            "-p",
            "terl-selector",
        ])
        .status()
        .expect("cargo runs");
    assert!(status.success(), "building the services failed");
    bin_dir
}

/// The address a service writes to `path` once it serves (`<run>/learner.addr`, …), waiting
/// up to `limit`. With `child` (the service), fails as soon as it exits, and kills it on a
/// timeout.
#[allow(dead_code)] // not every test binary that shares this module starts a service
pub fn wait_for_addr(path: &Path, mut child: Option<&mut Child>, limit: Duration) -> String {
    let start = Instant::now();
    loop {
        if let Ok(text) = std::fs::read_to_string(path) {
            if !text.trim().is_empty() {
                return text.trim().to_string();
            }
        }
        if let Some(c) = child.as_deref_mut() {
            if let Some(status) = c.try_wait().unwrap() {
                panic!(
                    "the service exited before writing {}: {status}",
                    path.display()
                );
            }
        }
        if start.elapsed() > limit {
            if let Some(c) = child.as_deref_mut() {
                let _ = c.kill();
                let _ = c.wait();
            }
            panic!("{} never appeared within {limit:?}", path.display());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Writes `<dir>/run.toml`: the smallest run a learner starts on (reach-v3, one environment,
/// 16-unit networks, one thread, no calibration), for tests of a service's start and stop.
#[allow(dead_code)] // not every test binary that shares this module starts a service
pub fn tiny_run_file(dir: &Path) -> PathBuf {
    let config = dir.join("run.toml");
    std::fs::write(
        &config,
        "tasks = \"reach-v3\"\nnum_envs = 1\n\
         [sac]\npolicy_hidden = [16]\ncritic_hidden = [16]\nbatch_size = 16\nthreads = 1\n\
         [cluster]\nlearner_calibrate_secs = 0\n",
    )
    .unwrap();
    config
}
