//! The paper's protocol as commands: `deploy/experiments/run.sh` at smoke scale runs MT1-Ind
//! (MTSAC and TERL), MT10 (MTSAC, TERL cold and TERL from the MT1-Ind datasets) and the MT-Test
//! zero-shot evaluation as real local clusters, and `terl report` builds the table and curves
//! from the run folders.
#![allow(clippy::too_many_lines)] // a scenario test reads start to end

mod common;

use std::path::Path;
use std::process::Command;

use common::{service_binaries, workspace};

fn tag() -> String {
    format!("-it{}", std::process::id())
}

fn run_experiment(root: &Path, runs: &Path, experiment: &str) -> String {
    run_experiment_with(root, runs, experiment, &[])
}

fn run_experiment_with(root: &Path, runs: &Path, experiment: &str, extra: &[&str]) -> String {
    let out = Command::new(root.join("deploy/experiments/run.sh"))
        .current_dir(root)
        .args([
            experiment, "--scale", "smoke", "--seeds", "1", "--actors", "1",
        ])
        .args(extra)
        .args(["--no-build", "--runs-root", runs.to_str().unwrap()])
        // Run ids are machine-wide (shared-memory names): a tag keeps these apart from any
        // experiment running on the same machine.
        .args(["--tag", &format!("it{}", std::process::id())])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{experiment}: {err}");
    err
}

/// Builds the service binaries; the experiment scripts run `target/release` binaries, so in
/// another profile these tests fail instead of passing without running.
fn release_binaries_built() {
    service_binaries();
    let release = Path::new(env!("CARGO_BIN_EXE_terl"))
        .parent()
        .and_then(Path::file_name)
        .is_some_and(|n| n == "release");
    assert!(
        release,
        "the experiment scripts run target/release binaries: run this test with --release \
         (./deploy/test.sh does)"
    );
}

#[test]
fn experiment_scripts_train_evaluate_and_report() {
    release_binaries_built();
    let root = workspace();
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path();
    // A bad option is refused before anything runs.
    for bad in ["0", "x", "1.5"] {
        let out = Command::new(root.join("deploy/experiments/run.sh"))
            .current_dir(&root)
            .args(["mt10", "--learner-threads", bad, "--no-build"])
            .args(["--runs-root", runs.to_str().unwrap()])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--learner-threads {bad}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--learner-threads"));
    }
    // A variant names run folders and report groups: only a plain short label is taken, and
    // only where it has an effect.
    for (experiment, bad) in [
        ("mt1-ind", "Async"),
        ("mt1-ind", "a b"),
        ("mt1-ind", "-x"),
        ("mt1-ind", "a/b"),
        // A dash would let "coffee" + "push" name the same run as coffee-push.
        ("mt1-ind", "coffee-"),
        ("mt10", "abcdefghijklmnopqrstuvwxy"),
        ("mt-test", "x"),
        ("terl-pipeline", "x"),
    ] {
        let out = Command::new(root.join("deploy/experiments/run.sh"))
            .current_dir(&root)
            .args([experiment, "--variant", bad, "--no-build"])
            .args(["--runs-root", runs.to_str().unwrap()])
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "--variant {bad:?}");
        assert!(String::from_utf8_lossy(&out.stderr).contains("--variant"));
    }
    run_experiment(&root, runs, "mt1-ind");
    for id in ["mt1-ind-mtsac-reach-s1", "mt1-ind-terl-reach-s1"] {
        let run = runs.join(format!("{id}{}", tag()));
        assert!(
            run.join("eval-final.json").is_file(),
            "{id}: no final evaluation"
        );
        assert!(run.join("checkpoints/final.safetensors").is_file(), "{id}");
    }
    let terl_run = runs.join(format!("mt1-ind-terl-reach-s1{}", tag()));
    assert!(terl_run.join("tep-dataset.mcap").is_file());
    // A finished run is not trained again.
    let again = run_experiment(&root, runs, "mt1-ind");
    assert!(again.contains("done already"), "{again}");
    // A finished run of other settings under the same id is neither skipped nor touched.
    let mtsac_config = runs.join(format!("mt1-ind-mtsac-reach-s1{}/config.toml", tag()));
    let original = std::fs::read_to_string(&mtsac_config).unwrap();
    std::fs::write(
        &mtsac_config,
        original.replace("tasks = \"reach-v3\"", "tasks = \"push-v3\""),
    )
    .unwrap();
    let out = Command::new(root.join("deploy/experiments/run.sh"))
        .current_dir(&root)
        .args([
            "mt1-ind", "--scale", "smoke", "--seeds", "1", "--actors", "1",
        ])
        .args(["--algorithms", "mtsac", "--no-build"])
        .args(["--runs-root", runs.to_str().unwrap()])
        .args(["--tag", &format!("it{}", std::process::id())])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("holds a finished run of other settings"),
        "{err}"
    );
    assert!(runs
        .join(format!("mt1-ind-mtsac-reach-s1{}/eval-final.json", tag()))
        .is_file());
    std::fs::write(&mtsac_config, original).unwrap();

    let log = run_experiment(&root, runs, "mt10");
    assert!(log.contains("mt10-terl-from-mt1-ind-s1"), "{log}");
    // CARE, the third row of Table I, through the same command, cluster and evaluation.
    run_experiment_with(&root, runs, "mt10", &["--algorithms", "care"]);
    let care = runs.join(format!("mt10-care-s1{}", tag()));
    assert!(
        care.join("eval-final.json").is_file(),
        "CARE: no final evaluation"
    );
    let care_cfg = std::fs::read_to_string(care.join("config.toml")).unwrap();
    assert!(care_cfg.contains("algorithm = \"care\""), "{care_cfg}");
    let from = runs.join(format!("mt10-terl-from-mt1-ind-s1{}", tag()));
    let learner = std::fs::read_to_string(from.join("learner.log")).unwrap();
    assert!(
        learner.contains("TEP buffer started from a dataset"),
        "{learner}"
    );
    // A learner checkpoint records its task order: a swapped --trained-tasks is refused, and a
    // checkpoint copied out of its run folder still knows its tasks.
    let mtsac = runs.join(format!("mt10-mtsac-s1{}", tag()));
    let terl = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_terl"))
            .args(args)
            .output()
            .unwrap()
    };
    let swapped = terl(&[
        "eval",
        "--checkpoint",
        mtsac.to_str().unwrap(),
        "--trained-tasks",
        "push-v3,reach-v3",
        "--episodes-per-task",
        "1",
    ]);
    assert!(!swapped.status.success());
    let err = String::from_utf8_lossy(&swapped.stderr);
    assert!(err.contains("trained on [reach-v3, push-v3]"), "{err}");
    let lone = runs.join("lone.safetensors");
    std::fs::copy(mtsac.join("checkpoints/final.safetensors"), &lone).unwrap();
    let out = terl(&[
        "eval",
        "--checkpoint",
        lone.to_str().unwrap(),
        "--episodes-per-task",
        "1",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    std::fs::remove_file(&lone).unwrap();
    run_experiment(&root, runs, "mt-test");
    let zero_shot: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            runs.join(format!("mt-test-from-mtsac-s1{}/eval-final.json", tag())),
        )
        .unwrap(),
    )
    .unwrap();
    let tasks: Vec<&str> = zero_shot["tasks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["task"].as_str().unwrap())
        .collect();
    assert_eq!(tasks, ["door-close-v3", "lever-pull-v3"]);
    assert!(zero_shot["tasks"][0]["trained"] == false);

    let mut args: Vec<String> = vec!["report".into()];
    for entry in std::fs::read_dir(runs).unwrap() {
        let p = entry.unwrap().path();
        if p.is_dir() {
            args.push(p.display().to_string());
        }
    }
    let report_dir = runs.join("report");
    args.extend(["--out".into(), report_dir.display().to_string()]);
    // The qualitative figure from one run per algorithm (their final checkpoints).
    args.push("--frames-from".into());
    for id in ["mt10-mtsac-s1", "mt10-terl-s1"] {
        args.push(runs.join(format!("{id}{}", tag())).display().to_string());
    }
    let out = Command::new(env!("CARGO_BIN_EXE_terl"))
        .args(&args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let md = std::fs::read_to_string(report_dir.join("results.md")).unwrap();
    for row in [
        "| mt1-ind | mtsac |",
        "| mt1-ind | terl |",
        "| mt10 | mtsac |",
        "| mt10 | terl |",
        "| mt10 | terl (from-mt1-ind) |",
        "| mt-test | mtsac |",
        "| mt10 | care |",
        "| mt-test | care |",
    ] {
        assert!(md.contains(row), "no row {row} in\n{md}");
    }
    // Training reports of several runs go under --out, never into the run folders.
    let one = format!("mt1-ind-mtsac-reach-s1{}", tag());
    assert!(report_dir
        .join("runs")
        .join(&one)
        .join("report.md")
        .is_file());
    assert!(!runs.join(&one).join("report.md").exists());
    for chart in ["mt10-eval-success.png", "mt1-ind-eval-return.svg"] {
        assert!(report_dir.join(chart).is_file(), "{chart}");
    }
    // The qualitative figure: per task a grid of one row per run, three frames of 240×240 each.
    assert!(md.contains("## What the final policies do"), "{md}");
    for task in ["reach-v3", "push-v3"] {
        let png = report_dir.join(format!("frames/mt10-{task}.png"));
        assert!(md.contains(&format!("(frames/mt10-{task}.png)")), "{md}");
        let img = image::open(&png).unwrap();
        assert_eq!((img.width(), img.height()), (3 * 240 + 2 * 4, 2 * 240 + 4));
    }
}

/// The paper's two stages as one command at smoke scale: each task alone until its planner
/// gate is open and it has selected its samples (not the budget cap), the planner trained
/// offline on the PTR-selected datasets and scored on trajectories held out of them (F against
/// the true step gaps; AN in the environment, on the goal variations the actors recorded), and
/// the multi-task run starting from that planner, whose tasks are validated at start.
#[test]
fn terl_pipeline_runs_stage_one_the_offline_planner_and_stage_three() {
    release_binaries_built();
    let root = workspace();
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path();
    let log = run_experiment(&root, runs, "terl-pipeline");
    for task in ["reach", "push"] {
        let run = runs.join(format!("pipeline-stage1-{task}-s1{}", tag()));
        let learner = std::fs::read_to_string(run.join("learner.log")).unwrap();
        assert!(
            learner.contains("planner ready"),
            "{task}: stage 1 did not stop on its planner condition\n{learner}"
        );
        assert!(run.join("tep-dataset.mcap").metadata().unwrap().len() > 0);
    }
    let planner_dir = runs.join(format!("pipeline-planner-s1{}", tag()));
    assert!(planner_dir.join("planner.safetensors").is_file(), "{log}");
    let eval: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(planner_dir.join("eval.json")).unwrap())
            .unwrap();
    let tasks = eval["tasks"].as_array().unwrap();
    assert_eq!(tasks.len(), 2, "{eval}");
    for t in tasks {
        assert!(t["f"]["pairs"].as_u64().unwrap() > 0, "{t}");
        assert!(t["f"]["spearman"].as_f64().is_some(), "{t}");
        // The variations the actors recorded let AN run from the held-out starts.
        assert!(t["random"]["episodes"].as_u64().unwrap() > 0, "{t}");
    }
    let stage3 = runs.join(format!("mt10-terl-pipeline-s1{}", tag()));
    assert!(stage3.join("eval-final.json").is_file(), "{log}");
    let config = std::fs::read_to_string(stage3.join("config.toml")).unwrap();
    assert!(config.contains("init_planner"), "{config}");
    let learner = std::fs::read_to_string(stage3.join("learner.log")).unwrap();
    assert_eq!(
        learner.matches("planner validated for the task").count(),
        2,
        "both tasks validated from the stage-1 data at start\n{learner}"
    );
    // Finished stages are not run again.
    let again = run_experiment(&root, runs, "terl-pipeline");
    assert_eq!(again.matches("done already").count(), 4, "{again}");
}
