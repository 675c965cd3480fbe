//! `terl report` on a run whose episode log has a damaged record length: the report is made
//! from the episodes before the damage, and the damage is named on stderr (the reader once
//! aborted on a multi-exabyte allocation here).

use std::process::Command;

use terl_telemetry::EpisodeLogWriter;
use terl_wire::EpisodeSummary;

fn episode(i: u64) -> EpisodeSummary {
    EpisodeSummary {
        task: "reach-v3".into(),
        actor_id: 0,
        episode_index: i,
        episode_return: i as f64,
        success: i.is_multiple_of(2),
        length: 500,
        policy_version: i,
        guided_steps: 0,
        missed_before: 0,
    }
}

#[test]
fn report_keeps_the_episodes_before_a_damaged_record_length() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let path = run.join("episodes.mcap");
    let mut w = EpisodeLogWriter::create(&path).unwrap();
    for i in 0..60 {
        w.write(&episode(i), 1 + i).unwrap();
        if i == 29 {
            w.flush().unwrap(); // episodes 0..30 in the second chunk, 30..60 in the third
        }
    }
    w.finish().unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    // Walk the top-level records (after the 8-byte magic) to the third chunk (opcode 0x06).
    let (mut at, mut seen) = (8usize, 0);
    loop {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        if bytes[at] == 0x06 {
            seen += 1;
            if seen == 3 {
                break;
            }
        }
        at += 9 + len;
    }
    bytes[at + 1..at + 9].copy_from_slice(&(5u64 << 60).to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();

    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(["report", run.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{}\n{stderr}", out.status);
    assert!(
        stderr.contains("episodes.mcap is read only in part")
            && stderr.contains(&format!("claims {} bytes", 5u64 << 60))
            && stderr.contains("using the 30 records"),
        "{stderr}"
    );
    assert_eq!(
        stderr.matches("read only in part").count(),
        1,
        "one damage, one message: {stderr}"
    );
    let md = std::fs::read_to_string(run.join("report.md")).unwrap();
    // Episodes 0..30 of reach-v3: every other one a success, returns 0..29 (mean 14.5).
    assert!(
        md.contains("| reach-v3 | 30 | 50.0 % | 50.0 % | 14.5 | 500 |"),
        "{md}"
    );
}

/// Out-of-range options are refused while the flags are parsed (exit 2), before anything is
/// allocated or written: huge resample counts and windows; and a final evaluation whose counts
/// contradict each other is refused.
#[test]
fn report_refuses_unbounded_options_and_impossible_final_evaluations() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    let terl = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_terl"))
            .args(args)
            .output()
            .unwrap()
    };
    let out_dir = dir.path().join("out");
    let (r, o) = (run.to_str().unwrap(), out_dir.to_str().unwrap());
    for (flag, value) in [
        ("--bootstrap-reps", "18446744073709551615"),
        ("--bootstrap-reps", "1000000000"),
        ("--window", "18446744073709551615"),
        ("--last-evals", "18446744073709551615"),
    ] {
        let out = terl(&["report", r, "--out", o, flag, value]);
        // Refused while the flags are parsed (clap's usage error).
        assert_eq!(out.status.code(), Some(2), "{flag} {value}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(flag) && !err.contains("panicked"), "{err}");
    }
    assert!(!out_dir.exists(), "nothing is written for refused options");
    // A final evaluation with 4200 successes in 50 episodes, or 0 episodes, is not a result.
    std::fs::write(
        run.join("config.toml"),
        "tasks = \"reach-v3\"\nnum_envs = 1\n[train]\ntotal_env_steps = 1000\n",
    )
    .unwrap();
    for (successes, episodes) in [(4200, 50), (0, 0)] {
        let eval = serde_json::json!({
            "mean_success_rate": 0.5, "mean_return": 1.0, "episodes_per_task": episodes,
            "tasks": [{"task": "reach-v3", "episodes": episodes, "successes": successes,
                       "success_rate": 0.5, "mean_return": 1.0}]
        });
        std::fs::write(run.join("eval-final.json"), eval.to_string()).unwrap();
        let out = terl(&["report", r, "--out", o]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{successes}/{episodes}: {err}");
        assert!(err.contains("episodes"), "{err}");
    }
}

/// Several runs, some with a damaged final evaluation: the report covers the others, names
/// each damaged one with its reason in `results.md` and on stderr, and exits 1 so a script
/// notices that a run is missing from the comparison. A link to itself or a pipe under the
/// file's name is damage, not "no final evaluation", and a pipe is never opened (it would wait
/// for a writer forever). Folders that are not runs are only noted; a folder named twice is
/// read once.
#[test]
fn a_run_left_out_of_a_multi_run_report_is_named_and_fails_the_command() {
    let dir = tempfile::tempdir().unwrap();
    let config = "experiment = \"x\"\ntasks = \"reach-v3\"\nnum_envs = 1\n[train]\ntotal_env_steps = 1000\nseed = SEED\n";
    let eval = serde_json::json!({
        "mean_success_rate": 0.5, "mean_return": 1.0, "episodes_per_task": 50,
        "tasks": [{"task": "reach-v3", "episodes": 50, "successes": 25,
                   "success_rate": 0.5, "mean_return": 1.0}]
    })
    .to_string();
    let mut runs = Vec::new();
    for seed in 1..=9 {
        let run = dir.path().join(format!("x-mtsac-s{seed}"));
        std::fs::create_dir_all(&run).unwrap();
        std::fs::write(
            run.join("config.toml"),
            config.replace("SEED", &seed.to_string()),
        )
        .unwrap();
        let final_eval = run.join("eval-final.json");
        match seed {
            // Cut in the middle (a copy interrupted by a full disk).
            2 => std::fs::write(&final_eval, &eval[..eval.len() / 2]).unwrap(),
            4 => std::os::unix::fs::symlink("eval-final.json", &final_eval).unwrap(),
            5 => assert!(Command::new("mkfifo")
                .arg(&final_eval)
                .status()
                .unwrap()
                .success()),
            // The rate contradicts the counts.
            6 => std::fs::write(
                &final_eval,
                eval.replace("\"success_rate\":0.5", "\"success_rate\":0.1"),
            )
            .unwrap(),
            // Another run's evaluation: of a checkpoint trained on other tasks.
            8 => std::fs::write(
                &final_eval,
                eval.replace("\"tasks\":[", "\"trained_tasks\":[\"push-v3\"],\"tasks\":["),
            )
            .unwrap(),
            // A task the run does not have, which would enter the mean return.
            9 => std::fs::write(
                &final_eval,
                eval.replace(
                    "\"tasks\":[",
                    "\"tasks\":[{\"task\":\"door-close-v3\",\"episodes\":50,\"successes\":0,\"success_rate\":0.0,\"mean_return\":1.0},",
                ),
            )
            .unwrap(),
            _ => std::fs::write(&final_eval, &eval).unwrap(),
        }
        runs.push(run);
    }
    runs.push(dir.path().join("x-mtsac-s1/"));
    // Evaluations whose run file is missing: nothing says what they measured.
    let orphan = dir.path().join("x-orphan");
    std::fs::create_dir_all(&orphan).unwrap();
    std::fs::write(orphan.join("eval-final.json"), &eval).unwrap();
    runs.push(orphan);
    // The same with only a later segment of the in-run evaluations.
    let orphan_segment = dir.path().join("x-orphan-segment");
    std::fs::create_dir_all(&orphan_segment).unwrap();
    std::fs::write(orphan_segment.join("eval.2.mcap"), b"").unwrap();
    runs.push(orphan_segment);
    let not_a_run = dir.path().join("notes");
    std::fs::create_dir_all(&not_a_run).unwrap();
    runs.push(not_a_run);
    let out_dir = dir.path().join("out");
    let out = Command::new("timeout")
        .arg("120")
        .arg(env!("CARGO_BIN_EXE_terl"))
        .arg("report")
        .args(&runs)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("6 run folder(s) left out"), "{err}");
    assert!(err.contains("notes is not a run folder"), "{err}");
    assert!(err.contains("given twice"), "{err}");
    let md = std::fs::read_to_string(out_dir.join("results.md")).unwrap();
    let (tables, left) = md.split_once("## Run folders left out").expect(&md);
    for (seed, why) in [
        (2, "not JSON"),
        (4, "cannot open"),
        (5, "not a regular file"),
        (6, "success_rate 0.1 but 25 successes in 50"),
        (8, "not this run's evaluation"),
        (9, "door-close-v3, which is not a task of this run"),
    ] {
        let line = left
            .lines()
            .find(|l| l.contains(&format!("x-mtsac-s{seed}`")))
            .unwrap_or_else(|| panic!("seed {seed} not listed: {left}"));
        assert!(line.contains(why), "seed {seed}: {line}");
    }
    // Evaluations without their run file are named on stderr (a run whose services were
    // started by hand has no config.toml), not taken for an empty folder, and not in a table.
    for (folder, file) in [
        ("x-orphan", "eval-final.json"),
        ("x-orphan-segment", "eval.2.mcap"),
    ] {
        assert!(
            err.lines().any(|l| l.contains(&format!(
                "{folder} has evaluations ({file}) but no config.toml"
            ))),
            "{folder}: {err}"
        );
        assert!(!left.contains(&format!("{folder}`")), "{left}");
    }
    for seed in [1, 3, 7] {
        assert!(!left.contains(&format!("x-mtsac-s{seed}`")), "{left}");
    }
    assert!(!left.contains("notes"), "{left}");
    // The three readable seeds are in the table.
    assert!(
        tables.contains("| x | mtsac |") && tables.contains("| 3 |"),
        "{tables}"
    );
}

#[test]
fn a_run_folder_whose_name_is_not_utf8_is_reported_and_a_mistyped_one_is_not_created() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().unwrap();
    let run = dir
        .path()
        .join(std::ffi::OsStr::from_bytes(b"x-mtsac-s1-\xff"));
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(
        run.join("config.toml"),
        "experiment = \"x\"\ntasks = \"reach-v3\"\nnum_envs = 1\n[train]\ntotal_env_steps = 1000\nseed = 1\n",
    )
    .unwrap();
    let eval = serde_json::json!({
        "mean_success_rate": 0.5, "mean_return": 1.0, "episodes_per_task": 50,
        "tasks": [{"task": "reach-v3", "episodes": 50, "successes": 25,
                   "success_rate": 0.5, "mean_return": 1.0}]
    });
    std::fs::write(run.join("eval-final.json"), eval.to_string()).unwrap();
    let out_dir = dir.path().join("out");
    let out = Command::new("timeout")
        .arg("120")
        .arg(env!("CARGO_BIN_EXE_terl"))
        .arg("report")
        .arg(&run)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(0), "{err}");
    let json = std::fs::read_to_string(out_dir.join("results.json")).unwrap();
    assert!(json.contains("x-mtsac-s1-\u{fffd}"), "{json}");

    let typo = dir.path().join("runs/mt10-mtsac-s9/nested");
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .arg("report")
        .arg(&typo)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("is not a folder"), "{err}");
    assert!(!dir.path().join("runs").exists(), "nothing was created");
}

/// A report into a folder that holds an earlier report of other runs names the earlier files
/// it did not rewrite (a chart of an experiment no longer reported), and leaves them in place.
#[test]
fn files_of_an_earlier_report_into_the_same_folder_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let eval = serde_json::json!({
        "mean_success_rate": 0.5, "mean_return": 1.0, "episodes_per_task": 50,
        "tasks": [{"task": "reach-v3", "episodes": 50, "successes": 25,
                   "success_rate": 0.5, "mean_return": 1.0}]
    })
    .to_string();
    let mut runs = Vec::new();
    for (experiment, seed) in [("a", 1), ("a", 2), ("b", 1)] {
        let run = dir.path().join(format!("{experiment}-mtsac-s{seed}"));
        std::fs::create_dir_all(&run).unwrap();
        std::fs::write(
            run.join("config.toml"),
            format!(
                "experiment = \"{experiment}\"\ntasks = \"reach-v3\"\nnum_envs = 1\n[train]\ntotal_env_steps = 1000\nseed = {seed}\n"
            ),
        )
        .unwrap();
        std::fs::write(run.join("eval-final.json"), &eval).unwrap();
        runs.push(run);
    }
    let out_dir = dir.path().join("out");
    let report = |runs: &[std::path::PathBuf]| {
        let out = Command::new(env!("CARGO_BIN_EXE_terl"))
            .arg("report")
            .args(runs)
            .arg("--out")
            .arg(&out_dir)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{err}");
        err
    };
    // A training log whose first segment is missing is named, not silently passed over.
    std::fs::write(runs[2].join("episodes.2.mcap"), b"").unwrap();
    let first = report(&runs);
    assert!(!first.contains("from an earlier report"), "{first}");
    assert!(first.contains("episodes.2.mcap is not read"), "{first}");
    let stale = out_dir.join("b-eval-success.svg");
    assert!(stale.is_file(), "{first}");
    let second = report(&runs[..2]);
    for chart in ["b-eval-success.svg", "b-eval-return.png"] {
        assert!(
            second.contains(&format!("{chart} is from an earlier report")),
            "{chart}: {second}"
        );
    }
    assert!(
        !second.contains("a-eval-success.svg is from"),
        "a rewritten chart is not stale: {second}"
    );
    assert!(stale.is_file(), "an earlier report's file is never removed");
    // A report already writing into the folder (here: its lock held) refuses a second one.
    // Its `sleep` outlives the killed `flock`: no pipe of the test is handed to it.
    let mut holder = Command::new("flock")
        .arg(&out_dir)
        .args(["sleep", "30"])
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut refused = None;
    for _ in 0..100 {
        let out = Command::new(env!("CARGO_BIN_EXE_terl"))
            .arg("report")
            .args(&runs)
            .arg("--out")
            .arg(&out_dir)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        if err.contains("another terl report is writing into") {
            refused = Some(out.status.code());
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    holder.kill().unwrap();
    holder.wait().unwrap();
    assert_eq!(refused, Some(Some(1)), "the second report was not refused");
}
