//! The container image's runtime stage is the folder `deploy/container/stage.sh` assembles
//! (binaries, libmujoco from the MuJoCo wheel, Meta-World assets, run files, env.sh). This
//! test stages into a temporary folder and runs the staged `terl` from elsewhere with only
//! env.sh's settings: a Python Meta-World trace replays through the staged library and assets
//! within the parity tolerances. With the assets variable pointed at an empty folder the same
//! replay fails, so it is the staged copy that was used.

use std::path::Path;
use std::process::Command;

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
