//! The statistics, charts and tables of `terl report` over run folders, checked by hand.

use std::path::PathBuf;

use terl_stats::Bootstrap;

use super::charts::*;
use super::runs::*;
use super::stats::*;
use super::tables::*;

fn opts() -> StatsOptions {
    StatsOptions {
        last_evals: 3,
        bootstrap: Bootstrap::with_reps(2000),
    }
}

fn run(alg: &str, seed: u64, curve: &[(u64, f64)]) -> RunEval {
    let mut r = RunEval {
        dir: PathBuf::from(format!("runs/{alg}-{seed}")),
        experiment: "mt10".into(),
        algorithm: alg.into(),
        seed,
        tasks: vec!["reach-v3".into(), "push-v3".into()],
        points: curve
            .iter()
            .map(|&(steps, s)| EvalPoint {
                env_steps: steps,
                mean_success: s,
                per_task_success: vec![s + 0.1, s - 0.1],
                mean_return: 100.0 * s,
                episodes_per_task: 50,
            })
            .collect(),
        has_final_eval: false,
        in_run: Vec::new(),
        networks: "3×256".into(),
    };
    r.in_run = r.points.clone();
    r
}

#[test]
fn groups_final_success_over_seeds_by_hand() {
    let runs = vec![
        run("mtsac", 1, &[(1000, 0.1), (2000, 0.4)]),
        run("terl", 1, &[(1000, 0.2), (2000, 0.5)]),
        run("mtsac", 2, &[(1000, 0.3), (2000, 0.6)]),
    ];
    let s = summarize(&runs, &opts()).unwrap();
    assert_eq!(s.len(), 2);
    let m = &s[0];
    assert_eq!(
        (m.algorithm.as_str(), m.seeds.clone()),
        ("mtsac", vec![1, 2])
    );
    // Final successes 40 % and 60 %: mean 50, sample std sqrt(200) = 14.14.
    assert!((m.success_mean - 50.0).abs() < 1e-9);
    assert!((m.success_std - 200f64.sqrt()).abs() < 1e-9);
    assert!((m.per_task[0].1 - 60.0).abs() < 1e-9 && (m.per_task[1].1 - 40.0).abs() < 1e-9);
    assert_eq!(m.paper_success, Some(68.4));
    assert_eq!(s[1].success_std, 0.0);
    assert_eq!(s[1].paper_success, Some(82.8));
    // Scores [[50, 30], [70, 50]]: IQM (50 + 50) / 2 = 50 and mean 50. Resampling each
    // task's two seeds, the smallest resample ({50, 50}, {30, 30}: IQM 40, mean 40) and the
    // largest (60) each have probability 1/16 > 2.5 %: both intervals are [40, 60].
    let f = m.final_eval.as_ref().unwrap();
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
    let flat: Vec<f64> = f.scores.concat();
    assert!(
        flat.iter()
            .zip([50.0, 30.0, 70.0, 50.0])
            .all(|(&a, b)| close(a, b)),
        "{flat:?}"
    );
    for c in [f.iqm, f.mean] {
        assert!(
            close(c.point, 50.0) && close(c.lower, 40.0) && close(c.upper, 60.0),
            "{c:?}"
        );
    }
    let summary = summary(&runs, &opts()).unwrap();
    // terl seed 1 (60, 40) against mtsac ({50, 70}, {30, 50}): ½ on each task.
    let c = &summary.comparisons[0];
    assert_eq!((c.x.as_str(), c.y.as_str()), ("terl", "mtsac"));
    assert!((c.final_eval.unwrap().point - 0.5).abs() < 1e-12);
    let md = markdown(&summary);
    assert!(
        md.contains(
            "| mt10 | mtsac | 50.0 [40.0, 60.0] | 50.0 [40.0, 60.0] | 50.0 ± 14.1 | 68.4 | 2 | 50 | 2k | 3×256 |"
        ),
        "{md}"
    );
    assert!(md.contains("| mt10 | terl | mtsac | 0.50 ["), "{md}");
    assert!(
        md.contains("| push-v3 | 40.0 ± 14.1 | 40.0 ± 0.0 |"),
        "{md}"
    );
}

#[test]
fn bands_interpolate_seeds_onto_their_common_steps() {
    let a = run("mtsac", 1, &[(0, 0.0), (100, 1.0)]);
    let b = run("mtsac", 2, &[(0, 0.0), (50, 0.0), (150, 1.0)]);
    let band = band(
        "mtsac",
        &[&a, &b],
        CurveMetric::Success,
        &Bootstrap::with_reps(200),
    )
    .unwrap()
    .unwrap();
    // Common range 0..100; grid = union of steps inside it: 0, 50, 100.
    let xs: Vec<f64> = band.points.iter().map(|p| p.0).collect();
    assert_eq!(xs, vec![0.0, 50.0, 100.0]);
    // Per task the run's success ± 10 points. At 50: seed 1 interpolates to 50 % (tasks 60,
    // 40), seed 2 is 0 % (10, −10) → IQM of −10, 10, 40, 60 = 25.
    assert!((band.points[1].1 - 25.0).abs() < 1e-9);
    // At 100: seed 1 100 % (110, 90), seed 2 halfway from 0 (at 50) to 100 (at 150) → 50
    // (60, 40) → IQM (60 + 90) / 2 = 75.
    assert!((band.points[2].1 - 75.0).abs() < 1e-9);
    for &(_, m, lo, hi) in &band.points {
        assert!(lo <= m && m <= hi);
    }
}

#[test]
fn charts_are_written_as_png_and_svg() {
    let dir = tempfile::tempdir().unwrap();
    let runs = vec![
        run("mtsac", 1, &[(0, 0.0), (1000, 0.4), (2000, 0.5)]),
        run("mtsac", 2, &[(0, 0.0), (1000, 0.2), (2000, 0.7)]),
        run("terl", 1, &[(0, 0.0), (1000, 0.5), (2000, 0.8)]),
    ];
    let (md, files) = write_results(&runs, dir.path(), &opts()).unwrap();
    let png = dir.path().join("mt10-eval-success.png");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    let img_w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    assert_eq!(img_w, 1000);
    let svg = std::fs::read_to_string(dir.path().join("mt10-eval-return.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("mtsac, 2 seeds") && svg.contains("terl, 1 seed"));
    assert_eq!(files.len(), 2 + 4);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("results.json")).unwrap())
            .unwrap();
    assert_eq!(json["groups"].as_array().unwrap().len(), 2);
    assert_eq!(json["comparisons"].as_array().unwrap().len(), 1);
    // Regenerated byte for byte: the bootstrap has a fixed seed.
    let again = tempfile::tempdir().unwrap();
    let (md2, _) = write_results(&runs, again.path(), &opts()).unwrap();
    assert_eq!(md, md2);
    for f in [
        "results.json",
        "mt10-eval-success.png",
        "mt10-eval-success.svg",
    ] {
        assert_eq!(
            std::fs::read(dir.path().join(f)).unwrap(),
            std::fs::read(again.path().join(f)).unwrap(),
            "{f}"
        );
    }
}

#[test]
fn a_run_folder_reads_progress_and_its_final_evaluation() {
    use terl_rl::train::{EvalReport, TrainProgress};
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.toml"),
        "experiment = \"x\"\nvariant = \"a\"\ntasks = \"reach-v3,push-v3\"\nnum_envs = 2\n\
         eval_envs_per_task = 2\n[train]\ntotal_env_steps = 3000\nseed = 7\n",
    )
    .unwrap();
    let line = |steps: u64, s: [f64; 2]| {
        serde_json::to_string(&TrainProgress {
            env_steps: steps,
            eval: Some(EvalReport {
                success_rate: (s[0] + s[1]) / 2.0,
                per_task_success: s.to_vec(),
                mean_return: 10.0,
                episodes: 4,
            }),
            ..Default::default()
        })
        .unwrap()
    };
    let progress = format!(
        "{}\n{}\n{}\n{{\"env_steps\": 9",
        line(1000, [0.0, 0.5]),
        serde_json::to_string(&TrainProgress::default()).unwrap(),
        line(3000, [1.0, 0.5])
    );
    std::fs::write(d.join("progress.jsonl"), progress).unwrap();
    let r = load_run(d).unwrap();
    assert_eq!(
        (r.experiment.as_str(), r.algorithm.as_str(), r.seed),
        ("x", "mtsac (a)", 7)
    );
    let steps: Vec<u64> = r.points.iter().map(|p| p.env_steps).collect();
    assert_eq!(steps, vec![1000, 3000], "the partial last line is skipped");
    // eval_envs_per_task × the default eval_episodes_per_env (5).
    assert_eq!(r.points[1].episodes_per_task, 10);
    // `terl eval --json` of the final checkpoint replaces the last point (tasks by name).
    std::fs::write(
        d.join(FINAL_EVAL),
        r#"{"mean_success_rate": 0.6, "mean_return": 20.0, "episodes_per_task": 50,
            "tasks": [{"task": "push-v3", "success_rate": 0.2},
                      {"task": "reach-v3", "success_rate": 1.0}]}"#,
    )
    .unwrap();
    let r = load_run(d).unwrap();
    let last = r.last().unwrap();
    assert_eq!((last.env_steps, last.episodes_per_task), (3000, 50));
    assert_eq!(last.per_task_success, vec![1.0, 0.2]);
    assert_eq!(r.points.len(), 2);
    // A final evaluation that lacks a trained task is an error naming it.
    std::fs::write(
        d.join(FINAL_EVAL),
        r#"{"mean_success_rate": 0.6, "mean_return": 1.0, "episodes_per_task": 50,
            "tasks": [{"task": "reach-v3", "success_rate": 1.0}]}"#,
    )
    .unwrap();
    let e = format!("{:#}", load_run(d).unwrap_err());
    assert!(e.contains("push-v3"), "{e}");
}

#[test]
fn tasks_trained_alone_are_averaged_per_seed_then_over_seeds() {
    let one = |task: &str, seed: u64, s: f64| RunEval {
        dir: PathBuf::from(format!("runs/{task}-{seed}")),
        experiment: "mt1-ind".into(),
        algorithm: "mtsac".into(),
        seed,
        tasks: vec![task.into()],
        points: vec![EvalPoint {
            env_steps: 100,
            mean_success: s,
            per_task_success: vec![s],
            mean_return: 0.0,
            episodes_per_task: 50,
        }],
        has_final_eval: true,
        in_run: Vec::new(),
        networks: "3×256".into(),
    };
    let runs = vec![
        one("door-open-v3", 1, 1.0),
        one("window-open-v3", 1, 0.5),
        one("door-open-v3", 2, 0.5),
        one("window-open-v3", 2, 0.0),
    ];
    let s = summarize(&runs, &opts()).unwrap();
    // Seed 1: (100 + 50) / 2 = 75; seed 2: 25 → mean 50, std sqrt(1250).
    assert_eq!(s[0].seeds, vec![1, 2]);
    assert!((s[0].success_mean - 50.0).abs() < 1e-9);
    assert!((s[0].success_std - 1250f64.sqrt()).abs() < 1e-9);
    assert_eq!(s[0].tasks, vec!["door-open-v3", "window-open-v3"]);
    assert!((s[0].per_task[0].1 - 75.0).abs() < 1e-9);
    // Seeds × tasks [[100, 50], [50, 0]]: IQM (50 + 50) / 2.
    assert_eq!(
        s[0].final_eval.as_ref().unwrap().scores,
        vec![vec![100.0, 50.0], vec![50.0, 0.0]]
    );
    assert!((s[0].final_eval.as_ref().unwrap().iqm.point - 50.0).abs() < 1e-9);
    // Only final evaluations: no second definition.
    assert_eq!(s[0].last_in_run, None);
    let b = band(
        "x",
        &runs.iter().collect::<Vec<_>>(),
        CurveMetric::Success,
        &Bootstrap::with_reps(200),
    )
    .unwrap()
    .unwrap();
    assert_eq!(b.points.len(), 1);
    assert!((b.points[0].1 - 50.0).abs() < 1e-9);
    // The same task twice for one seed is refused.
    let twice = vec![one("door-open-v3", 1, 1.0), one("door-open-v3", 1, 0.0)];
    assert!(summarize(&twice, &opts()).is_err());

    // A second group of the experiment on other tasks (a variant run on a subset): each
    // per-task cell is that task's, found by name, and a task a group lacks is a dash.
    let mut with_variant = runs.clone();
    for (task, seed, s) in [("window-open-v3", 1, 0.2), ("sweep-into-v3", 1, 0.9)] {
        let mut r = one(task, seed, s);
        r.algorithm = "mtsac (asynchronous)".into();
        with_variant.push(r);
    }
    let md = markdown(&summary(&with_variant, &opts()).unwrap());
    let row = |task: &str| {
        md.lines()
            .find(|l| l.starts_with(&format!("| {task} |")))
            .unwrap_or_else(|| panic!("no row for {task}: {md}"))
            .to_string()
    };
    assert_eq!(row("door-open-v3"), "| door-open-v3 | 75.0 ± 35.4 | — |");
    assert_eq!(
        row("window-open-v3"),
        "| window-open-v3 | 25.0 ± 35.4 | 20.0 ± 0.0 |"
    );
    assert_eq!(row("sweep-into-v3"), "| sweep-into-v3 | — | 90.0 ± 0.0 |");
}

#[test]
fn chart_names_of_distinct_experiments_never_collide() {
    assert_eq!(file_stem("mt10"), "mt10");
    assert_eq!(file_stem("mt1-ind"), "mt1-ind");
    let names = ["a/b", "a_b", "mt 10 ü", "mt 10 é", "", &"x".repeat(300)];
    let stems: Vec<String> = names.iter().map(|n| file_stem(n)).collect();
    for (i, a) in stems.iter().enumerate() {
        assert!(!a.is_empty() && a.len() <= 70, "{a}");
        assert!(a
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_'));
        for b in &stems[i + 1..] {
            assert_ne!(a, b);
        }
    }
}

#[test]
fn evaluations_that_do_not_fit_the_config_are_skipped_or_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("config.toml"),
        "tasks = \"reach-v3,push-v3\"\nnum_envs = 2\n[train]\ntotal_env_steps = 3000\n",
    )
    .unwrap();
    let line = |steps: u64, per: Vec<f64>| {
        serde_json::to_string(&terl_rl::train::TrainProgress {
            env_steps: steps,
            eval: Some(terl_rl::train::EvalReport {
                success_rate: 0.5,
                per_task_success: per,
                mean_return: 1.0,
                episodes: 2,
            }),
            ..Default::default()
        })
        .unwrap()
    };
    // One task short, one rate above 1, one good.
    let progress = [
        line(1000, vec![0.5]),
        line(2000, vec![0.5, 42.0]),
        line(3000, vec![0.5, 0.5]),
    ]
    .join("\n");
    std::fs::write(d.join("progress.jsonl"), progress).unwrap();
    let r = load_run(d).unwrap();
    assert_eq!(r.points.len(), 1);
    assert_eq!(r.points[0].env_steps, 3000);
    std::fs::write(
        d.join(FINAL_EVAL),
        r#"{"mean_success_rate": 0.5, "mean_return": 1.0, "episodes_per_task": 50,
            "tasks": [{"task": "reach-v3", "success_rate": 42},
                      {"task": "push-v3", "success_rate": 0.0}]}"#,
    )
    .unwrap();
    let e = format!("{:#}", load_run(d).unwrap_err());
    assert!(e.contains("[0, 1]"), "{e}");
}

#[test]
fn a_seed_without_a_task_is_noted() {
    let mut a = run("mtsac", 1, &[(1000, 0.5)]);
    let mut b = run("mtsac", 2, &[(1000, 1.0)]);
    a.tasks = vec!["reach-v3".into(), "push-v3".into()];
    b.tasks = vec!["reach-v3".into()];
    b.points[0].per_task_success = vec![1.0];
    let runs = [a, b];
    let s = summarize(&runs, &opts()).unwrap();
    assert_eq!(s[0].missing, vec![(2, "push-v3".to_string())]);
    // The score matrix keeps only the seed with every task.
    assert_eq!(s[0].final_eval.as_ref().unwrap().seeds, vec![1]);
    let md = markdown(&summary(&runs, &opts()).unwrap());
    assert!(md.contains("seed 2 has no evaluation of push-v3"), "{md}");
    assert!(md.contains("| 1 of 2 |"), "{md}");
}

#[test]
fn final_as_the_last_in_run_evaluations_beside_the_final_evaluation() {
    // In-run evaluations 20, 40, 60, 80 % (tasks ± 10), then a final evaluation of 10 %.
    let mut r = run(
        "mtsac",
        1,
        &[(1, 0.2), (2, 0.4), (3, 0.6), (4, 0.8), (5, 0.1)],
    );
    r.in_run.pop();
    r.has_final_eval = true;
    let s = summarize(&[r], &opts()).unwrap();
    let f = s[0].final_eval.as_ref().unwrap();
    assert!((f.scores[0][0] - 20.0).abs() < 1e-9 && f.scores[0][1].abs() < 1e-9);
    // The last 3 in-run: task 0 (50 + 70 + 90) / 3 = 70, task 1 50.
    let l = s[0].last_in_run.as_ref().unwrap();
    assert!((l.scores[0][0] - 70.0).abs() < 1e-9 && (l.scores[0][1] - 50.0).abs() < 1e-9);
    assert_eq!((l.evals_used, l.env_steps), ((3, 3), (2, 4)));
    assert_eq!(l.kind, FinalKind::LastInRun);
    let md = markdown(&summary(&[run("terl", 1, &[(1, 0.5)])], &opts()).unwrap());
    assert!(
        md.contains("the final evaluation (`eval-final.json`"),
        "{md}"
    );
    assert!(
        md.contains("the mean of the last 3 in-run evaluations"),
        "{md}"
    );
    assert!(md.contains("1 run(s) without `eval-final.json`"), "{md}");
}
