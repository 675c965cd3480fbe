//! Evaluation results across runs: the Table-I-style summary and the learning curves of
//! `terl report`.
//!
//! A run folder contributes its **deterministic evaluations** (the policy's mean action on
//! each task's goal variations), never its training episodes:
//! - `progress.jsonl` of `terl train` (one line per evaluation, with the env steps);
//! - the in-run evaluations of a cluster run (`eval.mcap`, written by the selector);
//! - `eval-final.json`, a `terl eval --json` of the final checkpoint (all 50 goal variations
//!   per task), which is then the run's final point.
//!
//! Runs are grouped by experiment (the run file's `experiment`, else its `tasks`) and
//! algorithm; each group reports the **final** evaluation's success rate as mean ± standard
//! deviation over seeds (sample std, n − 1; 0 for one seed), with the number of seeds,
//! evaluation episodes per task and env steps stated, next to the paper's Table I. Curves put
//! one line per algorithm (mean over seeds) with the seeds' spread (± one std) shaded; they are
//! drawn by `plotters` as PNG (for documents) and SVG ([`crate::charts`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::Serialize;
use terl_runtime::RunConfig;

use crate::charts::{band, write_chart, Band, CurveMetric};

/// One deterministic evaluation of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EvalPoint {
    /// Environment steps collected when the evaluated policy was current.
    pub env_steps: u64,
    /// Mean over tasks of the per-task success rate (fraction, 0–1).
    pub mean_success: f64,
    /// Per task (in the run's task order), fraction of episodes with success at any step.
    pub per_task_success: Vec<f64>,
    /// Mean undiscounted episode return over all evaluation episodes.
    pub mean_return: f64,
    /// Evaluation episodes per task.
    pub episodes_per_task: usize,
}

/// The evaluations of one run folder.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunEval {
    pub dir: PathBuf,
    /// Experiment name (grouping key): the run file's `experiment`, else its `tasks`.
    pub experiment: String,
    /// `"mtsac"` or `"terl"`, followed by the run file's `variant` in parentheses if set.
    pub algorithm: String,
    /// The run's training seed (`[train] seed`).
    pub seed: u64,
    pub tasks: Vec<String>,
    /// In order of env steps.
    pub points: Vec<EvalPoint>,
}

impl EvalPoint {
    /// One finite success rate in [0, 1] per task (and the mean too).
    fn is_valid(&self, num_tasks: usize) -> bool {
        let rate = |v: f64| v.is_finite() && (0.0..=1.0).contains(&v);
        self.per_task_success.len() == num_tasks
            && self.per_task_success.iter().all(|&v| rate(v))
            && rate(self.mean_success)
            && self.mean_return.is_finite()
    }
}

impl RunEval {
    /// The last evaluation.
    pub fn last(&self) -> Option<&EvalPoint> {
        self.points.last()
    }
}

/// Reads a run folder's config and evaluations. A folder without any evaluation is an error
/// naming what was looked for.
pub fn load_run(dir: &Path) -> Result<RunEval> {
    let cfg_path = dir.join("config.toml");
    let cfg = RunConfig::load(&cfg_path)
        .with_context(|| format!("{} is not a run folder", dir.display()))?;
    let tasks: Vec<String> = terl_runtime::resolve_tasks(&cfg.tasks)?
        .into_iter()
        .map(String::from)
        .collect();
    let mut points = Vec::new();
    let progress = dir.join("progress.jsonl");
    if progress.exists() {
        points.extend(progress_points(
            &progress,
            cfg.eval_envs_per_task * cfg.train.eval_episodes_per_env,
        )?);
    }
    let (evals, cut) = crate::report::read_run_log::<terl_wire::EvalResult>(dir, "eval")?;
    for c in cut {
        eprintln!("{c}");
    }
    points.extend(evals.iter().map(|e| {
        let by_name: BTreeMap<&str, f64> = e
            .tasks
            .iter()
            .map(|t| (t.task.as_str(), t.success_rate))
            .collect();
        EvalPoint {
            env_steps: e.env_steps,
            mean_success: e.mean_success_rate,
            per_task_success: tasks
                .iter()
                .map(|t| by_name.get(t.as_str()).copied().unwrap_or(f64::NAN))
                .collect(),
            mean_return: e.mean_return,
            episodes_per_task: e.episodes_per_task as usize,
        }
    }));
    let before = points.len();
    points.retain(|p| p.is_valid(tasks.len()));
    if points.len() < before {
        eprintln!(
            "note: {}: {} evaluation(s) skipped (not one success rate in [0, 1] per task of its config)",
            dir.display(),
            before - points.len()
        );
    }
    points.sort_by_key(|p| p.env_steps);
    let final_eval = dir.join(FINAL_EVAL);
    if final_eval.exists() {
        let at = if cfg.train.total_env_steps > 0 {
            cfg.train.total_env_steps
        } else {
            points.last().map_or(0, |p| p.env_steps)
        };
        let p = final_eval_point(&final_eval, &tasks, at)?;
        anyhow::ensure!(
            p.is_valid(tasks.len()),
            "{}: success rates must be in [0, 1]",
            final_eval.display()
        );
        points.retain(|q| q.env_steps < p.env_steps);
        points.push(p);
    }
    anyhow::ensure!(
        !points.is_empty(),
        "{}: no evaluation found (progress.jsonl of `terl train`, or in-run evaluations of a cluster run)",
        dir.display()
    );
    Ok(RunEval {
        dir: dir.to_path_buf(),
        experiment: cfg.experiment.clone().unwrap_or_else(|| cfg.tasks.clone()),
        algorithm: match &cfg.variant {
            Some(v) => format!("{} ({v})", cfg.algorithm.as_str()),
            None => cfg.algorithm.as_str().to_string(),
        },
        seed: cfg.train.seed,
        tasks,
        points,
    })
}

/// File name of a run's final evaluation: `terl eval --checkpoint RUN/checkpoints/final.safetensors
/// --json > RUN/eval-final.json` (the experiment scripts write it). It is the run's last point,
/// at the run's `total_env_steps`, and replaces any in-run evaluation from there on.
pub const FINAL_EVAL: &str = "eval-final.json";

/// The point of a `terl eval --json` output, per task in `tasks` order (a task the file lacks
/// is an error).
fn final_eval_point(path: &Path, tasks: &[String], env_steps: u64) -> Result<EvalPoint> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    let field = |v: &serde_json::Value, k: &str| {
        v.get(k)
            .and_then(serde_json::Value::as_f64)
            .with_context(|| format!("{}: no number `{k}`", path.display()))
    };
    let entries = v
        .get("tasks")
        .and_then(serde_json::Value::as_array)
        .with_context(|| format!("{}: no `tasks` list", path.display()))?;
    let per_task_success = tasks
        .iter()
        .map(|t| {
            let e = entries
                .iter()
                .find(|e| e.get("task").and_then(serde_json::Value::as_str) == Some(t))
                .with_context(|| format!("{}: no result for {t}", path.display()))?;
            field(e, "success_rate")
        })
        .collect::<Result<Vec<f64>>>()?;
    Ok(EvalPoint {
        env_steps,
        mean_success: field(&v, "mean_success_rate")?,
        per_task_success,
        mean_return: field(&v, "mean_return")?,
        episodes_per_task: field(&v, "episodes_per_task")? as usize,
    })
}

/// The evaluations in a `terl train` `progress.jsonl`. A damaged last line (a run killed while
/// writing) is skipped; damage elsewhere is an error with its line number.
fn progress_points(path: &Path, episodes_per_task: usize) -> Result<Vec<EvalPoint>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let p: terl_rl::train::TrainProgress = match serde_json::from_str(line) {
            Ok(p) => p,
            Err(_) if i + 1 == lines.len() => {
                eprintln!("note: {} ends in a partial line; skipped", path.display());
                break;
            }
            Err(e) => anyhow::bail!("{}:{}: {e}", path.display(), i + 1),
        };
        if let Some(e) = p.eval {
            out.push(EvalPoint {
                env_steps: p.env_steps,
                mean_success: e.success_rate,
                per_task_success: e.per_task_success,
                mean_return: e.mean_return,
                episodes_per_task: episodes_per_task.max(1),
            });
        }
    }
    Ok(out)
}

/// The paper's Table I (success %, 5 seeds, 500 trials) for an experiment and algorithm.
pub fn paper_success(experiment: &str, algorithm: &str) -> Option<f64> {
    let v = match (experiment.to_ascii_lowercase().as_str(), algorithm) {
        ("mt1-ind", "mtsac") => 95.0,
        ("mt1-ind", "terl") => 95.4,
        ("mt10", "mtsac") => 68.4,
        ("mt10", "terl") => 82.8,
        ("mt-test", "mtsac") => 16.4,
        ("mt-test", "terl") => 19.4,
        ("mt20", "mtsac") => 63.4,
        ("mt20", "terl") => 68.8,
        _ => return None,
    };
    Some(v)
}

/// Mean and sample standard deviation (n − 1; 0 for fewer than two values).
pub fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len();
    if n == 0 {
        return (f64::NAN, f64::NAN);
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    if n < 2 {
        return (mean, 0.0);
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (mean, var.sqrt())
}

/// Final results of one (experiment, algorithm) group.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroupSummary {
    pub experiment: String,
    pub algorithm: String,
    pub seeds: Vec<u64>,
    pub runs: Vec<PathBuf>,
    pub tasks: Vec<String>,
    /// Final mean success over tasks (%), mean and std over seeds.
    pub success_mean: f64,
    pub success_std: f64,
    /// Per task: final success (%) mean and std over seeds.
    pub per_task: Vec<(String, f64, f64)>,
    /// Final mean return, mean over seeds.
    pub return_mean: f64,
    /// Smallest and largest env steps at the final evaluation over seeds.
    pub env_steps: (u64, u64),
    pub episodes_per_task: usize,
    pub paper_success: Option<f64>,
    /// `(seed, task)` pairs with no final evaluation while another seed of the group has one.
    pub missing: Vec<(u64, String)>,
}

/// Groups runs by (experiment, algorithm), in a stable order.
pub fn group_runs(runs: &[RunEval]) -> BTreeMap<(String, String), Vec<&RunEval>> {
    let mut groups: BTreeMap<(String, String), Vec<&RunEval>> = BTreeMap::new();
    for r in runs {
        groups
            .entry((r.experiment.clone(), r.algorithm.clone()))
            .or_default()
            .push(r);
    }
    groups
}

/// The final-evaluation summary of each group.
///
/// A seed's result is the mean over tasks of its runs' final per-task success: one run per
/// seed for a multi-task experiment (MT10), or one run per task and seed when each task trains
/// alone (MT1-Ind). A task evaluated twice for one seed is an error. The group reports the mean
/// and standard deviation of the seeds' results.
pub fn summarize(runs: &[RunEval]) -> Result<Vec<GroupSummary>> {
    let mut out = Vec::new();
    for ((experiment, algorithm), members) in group_runs(runs) {
        let mut tasks: Vec<String> = Vec::new();
        // seed → task → final success (%).
        let mut by_seed: BTreeMap<u64, BTreeMap<String, f64>> = BTreeMap::new();
        let mut finals: Vec<&EvalPoint> = Vec::new();
        for m in &members {
            let Some(last) = m.last() else { continue };
            finals.push(last);
            let seed = by_seed.entry(m.seed).or_default();
            for (t, s) in m.tasks.iter().zip(&last.per_task_success) {
                anyhow::ensure!(
                    seed.insert(t.clone(), 100.0 * s).is_none(),
                    "experiment {experiment} / {algorithm}: seed {} evaluates {t} in two runs (one is {})",
                    m.seed,
                    m.dir.display()
                );
                if !tasks.contains(t) {
                    tasks.push(t.clone());
                }
            }
        }
        let success: Vec<f64> = by_seed
            .values()
            .map(|per| per.values().sum::<f64>() / per.len().max(1) as f64)
            .collect();
        let (success_mean, success_std) = mean_std(&success);
        let per_task = tasks
            .iter()
            .map(|t| {
                let v: Vec<f64> = by_seed
                    .values()
                    .filter_map(|per| per.get(t).copied())
                    .collect();
                let (m, s) = mean_std(&v);
                (t.clone(), m, s)
            })
            .collect();
        let missing = by_seed
            .iter()
            .flat_map(|(seed, per)| {
                tasks
                    .iter()
                    .filter(|t| !per.contains_key(*t))
                    .map(move |t| (*seed, t.clone()))
            })
            .collect();
        let steps: Vec<u64> = finals.iter().map(|p| p.env_steps).collect();
        out.push(GroupSummary {
            missing,
            paper_success: paper_success(&experiment, &algorithm)
                .filter(|_| !algorithm.contains('(')),
            seeds: by_seed.keys().copied().collect(),
            runs: members.iter().map(|m| m.dir.clone()).collect(),
            return_mean: mean_std(&finals.iter().map(|p| p.mean_return).collect::<Vec<_>>()).0,
            env_steps: (
                steps.iter().copied().min().unwrap_or(0),
                steps.iter().copied().max().unwrap_or(0),
            ),
            episodes_per_task: finals
                .iter()
                .map(|p| p.episodes_per_task)
                .min()
                .unwrap_or(0),
            experiment,
            algorithm,
            tasks,
            success_mean,
            success_std,
            per_task,
        });
    }
    Ok(out)
}

fn steps_label(steps: (u64, u64)) -> String {
    let fmt = |s: u64| {
        if s >= 1_000_000 {
            format!("{:.2}M", s as f64 / 1e6)
        } else {
            format!("{:.0}k", s as f64 / 1e3)
        }
    };
    if steps.0 == steps.1 {
        fmt(steps.0)
    } else {
        format!("{}–{}", fmt(steps.0), fmt(steps.1))
    }
}

/// `results.md`: the Table-I-style table, then a per-task breakdown per experiment.
pub fn markdown(summaries: &[GroupSummary]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Evaluation results\n");
    let _ = writeln!(
        s,
        "Final deterministic evaluation (mean action) of each run; success = success at any step \
         of an episode, averaged over tasks. Mean ± std over seeds. The paper's Table I reports 5 \
         seeds and 500 trials at its own budget; Meta-World v3 tasks here use v2-style rewards.\n"
    );
    let _ = writeln!(
        s,
        "| experiment | algorithm | success % (ours) | paper % | seeds | eval episodes / task | env steps / run |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for g in summaries {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} ± {:.1} | {} | {} | {} | {} |",
            g.experiment,
            g.algorithm,
            g.success_mean,
            g.success_std,
            g.paper_success
                .map_or_else(|| "—".to_string(), |p| format!("{p:.1}")),
            g.seeds.len(),
            g.episodes_per_task,
            steps_label(g.env_steps)
        );
    }
    let mut experiments: Vec<&str> = summaries.iter().map(|g| g.experiment.as_str()).collect();
    experiments.dedup();
    for exp in experiments {
        let groups: Vec<&GroupSummary> = summaries.iter().filter(|g| g.experiment == exp).collect();
        let _ = writeln!(
            s,
            "\n## {exp}: per task (final success %, mean ± std over seeds)\n"
        );
        let header: Vec<String> = groups
            .iter()
            .map(|g| format!("{}, {}", g.algorithm, seeds_label(g.seeds.len())))
            .collect();
        let _ = writeln!(s, "| task | {} |", header.join(" | "));
        let _ = writeln!(s, "|---|{}", "---|".repeat(groups.len()));
        for (k, task) in groups[0].tasks.iter().enumerate() {
            let cells: Vec<String> = groups
                .iter()
                .map(|g| {
                    g.per_task
                        .get(k)
                        .map_or("—".into(), |(_, m, sd)| format!("{m:.1} ± {sd:.1}"))
                })
                .collect();
            let _ = writeln!(s, "| {task} | {} |", cells.join(" | "));
        }
        for g in &groups {
            for (seed, task) in &g.missing {
                let _ = writeln!(
                    s,
                    "\n**Note:** {} seed {seed} has no evaluation of {task}; that seed's mean is over its other tasks.",
                    g.algorithm
                );
            }
        }
        let _ = writeln!(
            s,
            "\nCurves: `{0}-eval-success.png` / `.svg`, `{0}-eval-return.png` / `.svg`.",
            file_stem(exp)
        );
    }
    s
}

fn seeds_label(n: usize) -> String {
    if n == 1 {
        "1 seed".into()
    } else {
        format!("{n} seeds")
    }
}

/// A file-name-safe form of an experiment name: ASCII letters, digits and `-` kept, anything
/// else `_`, at most 60 characters; when that changed the name (or it was empty), an FNV-1a
/// hash of the name is appended, so distinct names never share a chart file.
pub fn file_stem(experiment: &str) -> String {
    let safe: String = experiment
        .chars()
        .take(60)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if safe == experiment && !safe.is_empty() {
        return safe;
    }
    let hash = experiment.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{safe}-{:08x}", hash as u32)
}

/// Everything `terl report` writes for a set of runs: `results.md`, `results.json` and the
/// two charts per experiment. Returns the markdown and the files written.
pub fn write_results(runs: &[RunEval], out_dir: &Path) -> Result<(String, Vec<PathBuf>)> {
    let summaries = summarize(runs)?;
    let md = markdown(&summaries);
    let mut files = Vec::new();
    let md_path = out_dir.join("results.md");
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    files.push(md_path);
    let json_path = out_dir.join("results.json");
    let json = serde_json::json!({ "groups": summaries, "runs": runs });
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}", json_path.display()))?;
    files.push(json_path);
    let groups = group_runs(runs);
    let mut experiments: Vec<&String> = groups.keys().map(|(e, _)| e).collect();
    experiments.dedup();
    for exp in experiments {
        for metric in [CurveMetric::Success, CurveMetric::Return] {
            let bands: Vec<Band> = groups
                .iter()
                .filter(|((e, _), _)| e == exp)
                .filter_map(|((_, alg), members)| {
                    band(
                        &format!("{alg}, {}", seeds_label(members.len())),
                        members,
                        metric,
                    )
                })
                .collect();
            let (stem, what) = match metric {
                CurveMetric::Success => ("eval-success", "success"),
                CurveMetric::Return => ("eval-return", "return"),
            };
            files.extend(write_chart(
                out_dir,
                &format!("{}-{stem}", file_stem(exp)),
                &format!("{exp}: deterministic evaluation {what} (mean ± std over seeds)"),
                metric,
                &bands,
            )?);
        }
    }
    Ok((md, files))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(alg: &str, seed: u64, curve: &[(u64, f64)]) -> RunEval {
        RunEval {
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
        }
    }

    #[test]
    fn groups_final_success_over_seeds_by_hand() {
        let runs = vec![
            run("mtsac", 1, &[(1000, 0.1), (2000, 0.4)]),
            run("terl", 1, &[(1000, 0.2), (2000, 0.5)]),
            run("mtsac", 2, &[(1000, 0.3), (2000, 0.6)]),
        ];
        let s = summarize(&runs).unwrap();
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
        let md = markdown(&s);
        assert!(
            md.contains("| mt10 | mtsac | 50.0 ± 14.1 | 68.4 | 2 | 50 | 2k |"),
            "{md}"
        );
        assert!(
            md.contains("| push-v3 | 40.0 ± 14.1 | 40.0 ± 0.0 |"),
            "{md}"
        );
    }

    #[test]
    fn bands_interpolate_seeds_onto_their_common_steps() {
        let a = run("mtsac", 1, &[(0, 0.0), (100, 1.0)]);
        let b = run("mtsac", 2, &[(0, 0.0), (50, 0.0), (150, 1.0)]);
        let band = band("mtsac", &[&a, &b], CurveMetric::Success).unwrap();
        // Common range 0..100; grid = union of steps inside it: 0, 50, 100.
        let xs: Vec<f64> = band.points.iter().map(|p| p.0).collect();
        assert_eq!(xs, vec![0.0, 50.0, 100.0]);
        // At 50: seed 1 interpolates to 50 %, seed 2 is 0 % → mean 25.
        assert!((band.points[1].1 - 25.0).abs() < 1e-9);
        // At 100: seed 1 100 %, seed 2 halfway from 0 (at 50) to 100 (at 150) → 50; mean 75.
        assert!((band.points[2].1 - 75.0).abs() < 1e-9);
    }

    #[test]
    fn charts_are_written_as_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let runs = vec![
            run("mtsac", 1, &[(0, 0.0), (1000, 0.4), (2000, 0.5)]),
            run("mtsac", 2, &[(0, 0.0), (1000, 0.2), (2000, 0.7)]),
            run("terl", 1, &[(0, 0.0), (1000, 0.5), (2000, 0.8)]),
        ];
        let (_, files) = write_results(&runs, dir.path()).unwrap();
        let png = dir.path().join("mt10-eval-success.png");
        let bytes = std::fs::read(&png).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        let img_w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
        assert_eq!(img_w, 1000);
        let svg = std::fs::read_to_string(dir.path().join("mt10-eval-return.svg")).unwrap();
        assert!(
            svg.contains("<svg") && svg.contains("mtsac, 2 seeds") && svg.contains("terl, 1 seed")
        );
        assert_eq!(files.len(), 2 + 4);
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("results.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(json["groups"].as_array().unwrap().len(), 2);
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
        };
        let runs = vec![
            one("door-open-v3", 1, 1.0),
            one("window-open-v3", 1, 0.5),
            one("door-open-v3", 2, 0.5),
            one("window-open-v3", 2, 0.0),
        ];
        let s = summarize(&runs).unwrap();
        // Seed 1: (100 + 50) / 2 = 75; seed 2: 25 → mean 50, std sqrt(1250).
        assert_eq!(s[0].seeds, vec![1, 2]);
        assert!((s[0].success_mean - 50.0).abs() < 1e-9);
        assert!((s[0].success_std - 1250f64.sqrt()).abs() < 1e-9);
        assert_eq!(s[0].tasks, vec!["door-open-v3", "window-open-v3"]);
        assert!((s[0].per_task[0].1 - 75.0).abs() < 1e-9);
        let b = band("x", &runs.iter().collect::<Vec<_>>(), CurveMetric::Success).unwrap();
        assert_eq!(b.points.len(), 1);
        assert!((b.points[0].1 - 50.0).abs() < 1e-9);
        // The same task twice for one seed is refused.
        let twice = vec![one("door-open-v3", 1, 1.0), one("door-open-v3", 1, 0.0)];
        assert!(summarize(&twice).is_err());
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
        let s = summarize(&[a, b]).unwrap();
        assert_eq!(s[0].missing, vec![(2, "push-v3".to_string())]);
        assert!(markdown(&s).contains("seed 2 has no evaluation of push-v3"));
    }
}
