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
//! algorithm. Each group's final success is a seeds × tasks score matrix (%), under two
//! definitions: the run's final evaluation (`eval-final.json`), and per task the mean of its
//! last few in-run evaluations ([`StatsOptions::last_evals`]). Of each matrix the group reports
//! the IQM and the mean with stratified bootstrap intervals ([`terl_stats`], as rliable), the
//! mean ± standard deviation over seeds of each seed's mean over tasks (sample std, n − 1; 0 for
//! one seed), with the number of seeds, evaluation episodes per task, env steps and networks,
//! next to the paper's Table I; and for two algorithms of an experiment the probability of
//! improvement with its interval. Curves put one line per algorithm (the IQM over seeds ×
//! tasks) with its interval shaded; they are drawn by `plotters` as PNG (for documents) and SVG
//! ([`crate::charts`]).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::Serialize;
use terl_runtime::RunConfig;

use terl_stats::{Bootstrap, Interval, ScoreMatrix};

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
    /// `"mtsac"`, `"terl"` or `"care"`, followed by the run file's `variant` in parentheses if set.
    pub algorithm: String,
    /// The run's training seed (`[train] seed`).
    pub seed: u64,
    pub tasks: Vec<String>,
    /// In order of env steps: the in-run evaluations, then `eval-final.json` when the run has
    /// one (which replaces in-run evaluations from its env steps on).
    pub points: Vec<EvalPoint>,
    /// Whether the last point is the run's `eval-final.json`.
    pub has_final_eval: bool,
    /// Every valid in-run evaluation (`progress.jsonl` or `eval.mcap`), in order of env steps,
    /// including those at or after the final evaluation's env steps.
    #[serde(skip)]
    pub in_run: Vec<EvalPoint>,
    /// The networks of the run file, e.g. `3×256` (policy and critic) or `3×256; TEP 3×512`.
    pub networks: String,
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

/// The error of [`load_run`] for a folder that holds nothing to use (no run file, or a run
/// without any evaluation yet): nothing is lost by leaving it out. Every other error of
/// [`load_run`] means evaluations exist but cannot be used (damaged, cut, contradictory).
#[derive(Debug)]
pub struct NoEvaluations(pub String);

impl std::fmt::Display for NoEvaluations {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for NoEvaluations {}

/// `dirs` with each folder once, in order, compared by canonical path (`runs/a`, `runs/a/` and
/// `./runs/a` are one folder); each repeat is noted on stderr as
/// `note: <flag><dir> is given twice; <outcome>`.
pub(crate) fn distinct_dirs<'a>(
    dirs: &'a [PathBuf],
    flag: &str,
    outcome: &str,
) -> Vec<&'a PathBuf> {
    let mut seen = Vec::new();
    dirs.iter()
        .filter(|dir| {
            let key = dir.canonicalize().unwrap_or_else(|_| (*dir).clone());
            if seen.contains(&key) {
                eprintln!("note: {flag}{} is given twice; {outcome}", dir.display());
                return false;
            }
            seen.push(key);
            true
        })
        .collect()
}

/// Largest `eval-final.json` or `progress.jsonl` read (far above any real one: a 50-task final
/// evaluation is a few KB, a progress line a few hundred bytes).
const MAX_EVAL_FILE_BYTES: u64 = 64 << 20;

/// Whether a run's file is there: `Ok(false)` when nothing is at `path`, `Ok(true)` for a
/// regular file (a link to one included), an error for anything else (a dangling or looping
/// link, a folder, pipe or device, an unreadable folder), so that damage is never mistaken
/// for a missing file.
fn present_file(path: &Path) -> Result<bool> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(e).with_context(|| format!("cannot look at {}", path.display())),
        Ok(_) => {}
    }
    let meta =
        std::fs::metadata(path).with_context(|| format!("cannot open {}", path.display()))?;
    anyhow::ensure!(
        meta.is_file(),
        "{} is not a regular file (a folder, pipe, socket or device)",
        path.display()
    );
    Ok(true)
}

/// The text of a run's evaluation file, refused above [`MAX_EVAL_FILE_BYTES`].
fn read_eval_file(path: &Path) -> Result<String> {
    let len = std::fs::metadata(path)
        .with_context(|| format!("reading {}", path.display()))?
        .len();
    anyhow::ensure!(
        len <= MAX_EVAL_FILE_BYTES,
        "{} has {len} bytes, more than any evaluation file ({MAX_EVAL_FILE_BYTES} at most)",
        path.display()
    );
    std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))
}

/// Reads a run folder's config and evaluations. A folder without a run file or without any
/// evaluation is a [`NoEvaluations`] error naming what was looked for; damaged evaluations are
/// other errors.
pub fn load_run(dir: &Path) -> Result<RunEval> {
    let cfg_path = dir.join("config.toml");
    if !present_file(&cfg_path).with_context(|| format!("{}: its run file", dir.display()))? {
        return Err(NoEvaluations(format!(
            "{} is not a run folder (no config.toml)",
            dir.display()
        ))
        .into());
    }
    let cfg = RunConfig::load(&cfg_path)
        .with_context(|| format!("{}: its run file cannot be read", dir.display()))?;
    let tasks: Vec<String> = terl_runtime::resolve_tasks(&cfg.tasks)?
        .into_iter()
        .map(String::from)
        .collect();
    let mut points = Vec::new();
    let progress = dir.join("progress.jsonl");
    if present_file(&progress)? {
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
    let in_run = points.clone();
    let final_eval = dir.join(FINAL_EVAL);
    let has_final_eval = present_file(&final_eval)?;
    if has_final_eval {
        let at = if cfg.train.total_env_steps > 0 {
            cfg.train.total_env_steps
        } else {
            points.last().map_or(0, |p| p.env_steps)
        };
        // A zero-shot run folder (`run.sh mt-test`) evaluates another run's checkpoint and
        // names it in its cluster.txt; every other run evaluates a policy trained on its tasks.
        let info = dir.join("cluster.txt");
        let zero_shot = present_file(&info)?
            && read_eval_file(&info)?
                .lines()
                .any(|l| l.starts_with("source_run="));
        let p = final_eval_point(&final_eval, &tasks, at, zero_shot)?;
        anyhow::ensure!(
            p.is_valid(tasks.len()),
            "{}: success rates must be in [0, 1]",
            final_eval.display()
        );
        points.retain(|q| q.env_steps < p.env_steps);
        points.push(p);
    }
    if points.is_empty() {
        return Err(NoEvaluations(format!(
            "{}: no evaluation found (progress.jsonl of `terl train`, or in-run evaluations of a cluster run)",
            dir.display()
        ))
        .into());
    }
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
        has_final_eval,
        in_run,
        networks: networks_label(&cfg),
    })
}

/// `3×256` for three hidden layers of 256; `400-300` for unequal widths; `linear` for none.
fn layers_label(hidden: &[usize]) -> String {
    match hidden {
        [] => "linear".into(),
        [first, rest @ ..] if rest.iter().all(|h| h == first) => {
            format!("{}×{first}", hidden.len())
        }
        _ => hidden
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join("-"),
    }
}

/// The run file's networks: policy and critic (`π …, Q …` when they differ), CARE's encoder
/// (experts, context, encoding width), and for TERL the TEP's forward model (`TEP f …, AN …`
/// when its action network differs).
fn networks_label(cfg: &RunConfig) -> String {
    let (pi, q) = (
        layers_label(&cfg.sac.policy_hidden),
        layers_label(&cfg.sac.critic_hidden),
    );
    let sac = if pi == q {
        pi
    } else {
        format!("π {pi}, Q {q}")
    };
    if let Some(care) = &cfg.sac.care {
        // CARE's encoder: k experts (hidden → feature width), the context and its encoder.
        let experts = match care.expert_hidden.as_slice() {
            [] => String::new(),
            h => format!("{} → ", layers_label(h)),
        };
        let context = match care.context {
            terl_rl::CareContext::TaskEmbeddings => "task embeddings",
            terl_rl::CareContext::OneHot => "one-hot",
        };
        return format!(
            "{sac}; CARE {k} experts {experts}{f}, {context} → {e}",
            k = care.num_experts,
            f = care.feature_dim,
            e = care.encoding_dim
        );
    }
    if cfg.algorithm != terl_runtime::Algorithm::Terl {
        return sac;
    }
    let (f, an) = (
        layers_label(&cfg.tep.f_hidden),
        layers_label(&cfg.tep.an_hidden),
    );
    if f == an {
        format!("{sac}; TEP {f}")
    } else {
        format!("{sac}; TEP f {f}, AN {an}")
    }
}

/// File name of a run's final evaluation: `terl eval --checkpoint RUN/checkpoints/final.safetensors
/// --json > RUN/eval-final.json` (the experiment scripts write it). It is the run's last point,
/// at the run's `total_env_steps`, and replaces any in-run evaluation from there on.
pub const FINAL_EVAL: &str = "eval-final.json";

/// The point of a `terl eval --json` output, per task in `tasks` order (a task the file lacks
/// is an error).
fn final_eval_point(
    path: &Path,
    tasks: &[String],
    env_steps: u64,
    zero_shot: bool,
) -> Result<EvalPoint> {
    let text = read_eval_file(path)?;
    let v: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{} is not JSON", path.display()))?;
    // The evaluation must be of this run's policy on this run's tasks: the trained task list
    // it records is the run's own (a zero-shot run's: not), and it lists no other task.
    if let Some(trained) = v.get("trained_tasks").and_then(serde_json::Value::as_array) {
        let trained: Vec<&str> = trained
            .iter()
            .filter_map(serde_json::Value::as_str)
            .collect();
        let own = trained.iter().copied().eq(tasks.iter().map(String::as_str));
        anyhow::ensure!(
            own != zero_shot,
            "{}: made from a checkpoint trained on [{}]; {}",
            path.display(),
            trained.join(", "),
            if zero_shot {
                "this zero-shot run's tasks must be outside that list".to_string()
            } else {
                format!(
                    "this run trains [{}]: not this run's evaluation",
                    tasks.join(", ")
                )
            }
        );
        if let Some(t) = tasks
            .iter()
            .find(|t| zero_shot && trained.contains(&t.as_str()))
        {
            anyhow::bail!(
                "{}: {t} is among the trained tasks [{}]: not a zero-shot evaluation",
                path.display(),
                trained.join(", ")
            );
        }
    }
    let field = |v: &serde_json::Value, k: &str| {
        v.get(k)
            .and_then(serde_json::Value::as_f64)
            .with_context(|| format!("{}: no number `{k}`", path.display()))
    };
    let entries = v
        .get("tasks")
        .and_then(serde_json::Value::as_array)
        .with_context(|| format!("{}: no `tasks` list", path.display()))?;
    if let Some(other) = entries
        .iter()
        .filter_map(|e| e.get("task").and_then(serde_json::Value::as_str))
        .find(|t| !tasks.iter().any(|own| own == t))
    {
        anyhow::bail!(
            "{}: has a result for {other}, which is not a task of this run [{}]",
            path.display(),
            tasks.join(", ")
        );
    }
    let per_task_success = tasks
        .iter()
        .map(|t| {
            let mut found = entries
                .iter()
                .filter(|e| e.get("task").and_then(serde_json::Value::as_str) == Some(t));
            let e = found
                .next()
                .with_context(|| format!("{}: no result for {t}", path.display()))?;
            anyhow::ensure!(
                found.next().is_none(),
                "{}: {t} has two results",
                path.display()
            );
            let rate = field(e, "success_rate")?;
            if let Some(n) = e.get("episodes").and_then(serde_json::Value::as_f64) {
                anyhow::ensure!(
                    (1.0..=1e9).contains(&n) && n.fract() == 0.0,
                    "{}: {t} has {n} episodes (a whole number in 1..=1e9 expected)",
                    path.display()
                );
            }
            if let (Some(k), Some(n)) = (
                e.get("successes").and_then(serde_json::Value::as_f64),
                e.get("episodes").and_then(serde_json::Value::as_f64),
            ) {
                anyhow::ensure!(
                    (0.0..=n).contains(&k) && k.fract() == 0.0,
                    "{}: {t} has {k} successes in {n} episodes",
                    path.display()
                );
                anyhow::ensure!(
                    (rate - k / n).abs() <= 1e-9,
                    "{}: {t} has success_rate {rate} but {k} successes in {n} episodes",
                    path.display()
                );
            }
            Ok(rate)
        })
        .collect::<Result<Vec<f64>>>()?;
    let mean_success = field(&v, "mean_success_rate")?;
    for (what, rate) in per_task_success
        .iter()
        .map(|&r| ("a task's success_rate", r))
        .chain([("mean_success_rate", mean_success)])
    {
        anyhow::ensure!(
            (0.0..=1.0).contains(&rate),
            "{}: {what} {rate} is not in [0, 1]",
            path.display()
        );
    }
    let task_mean = per_task_success.iter().sum::<f64>() / per_task_success.len().max(1) as f64;
    anyhow::ensure!(
        (mean_success - task_mean).abs() <= 1e-9,
        "{}: mean_success_rate {mean_success} is not the mean of its tasks' success rates \
         ({task_mean})",
        path.display()
    );
    let episodes_per_task = field(&v, "episodes_per_task")?;
    anyhow::ensure!(
        episodes_per_task >= 1.0 && episodes_per_task.fract() == 0.0 && episodes_per_task <= 1e9,
        "{}: episodes_per_task {episodes_per_task} is not a whole number in 1..=1e9",
        path.display()
    );
    Ok(EvalPoint {
        env_steps,
        mean_success,
        per_task_success,
        mean_return: field(&v, "mean_return")?,
        episodes_per_task: episodes_per_task as usize,
    })
}

/// The evaluations in a `terl train` `progress.jsonl`. A damaged last line (a run killed while
/// writing) is skipped; damage elsewhere is an error with its line number.
fn progress_points(path: &Path, episodes_per_task: usize) -> Result<Vec<EvalPoint>> {
    let text = read_eval_file(path)?;
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
        ("mt1-ind", "care") => 95.2,
        ("mt10", "care") => 75.6,
        ("mt-test", "care") => 23.4,
        ("mt20", "care") => 64.6,
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

/// How `terl report` summarizes final success: the second definition of "final" and the
/// bootstrap of every interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StatsOptions {
    /// "Final" as the mean of a run's last this many in-run evaluations (fewer when it has
    /// fewer), beside its final evaluation.
    pub last_evals: usize,
    /// Resamples, coverage and seed of the stratified bootstrap intervals.
    pub bootstrap: Bootstrap,
}

impl Default for StatsOptions {
    fn default() -> Self {
        Self {
            last_evals: DEFAULT_LAST_EVALS,
            bootstrap: Bootstrap::default(),
        }
    }
}

/// In-run evaluations averaged for the second definition of final success unless told.
pub const DEFAULT_LAST_EVALS: usize = 3;

/// A point estimate with its 95 % stratified bootstrap interval, in % (success) or as a
/// probability (improvement).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Ci {
    pub point: f64,
    pub lower: f64,
    pub upper: f64,
}

impl From<Interval> for Ci {
    fn from(i: Interval) -> Self {
        Self {
            point: i.point,
            lower: i.lower,
            upper: i.upper,
        }
    }
}

impl Ci {
    /// `52.5 [41.0, 64.0]` with `digits` decimals.
    fn label(&self, digits: usize) -> String {
        format!(
            "{:.d$} [{:.d$}, {:.d$}]",
            self.point,
            self.lower,
            self.upper,
            d = digits
        )
    }
}

/// Which result of a run is its final success.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FinalKind {
    /// The run's last evaluation: `eval-final.json` (all goal variations) when it has one, else
    /// its last in-run evaluation.
    FinalEval,
    /// Per task, the mean of the run's last `last_evals` in-run evaluations.
    LastInRun,
}

/// The field's statistics of one group under one definition of final success, over the seeds
/// that have a score for every task of the group.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FinalStats {
    pub kind: FinalKind,
    /// Seeds in the score matrix (rows), ascending.
    pub seeds: Vec<u64>,
    /// The score matrix, seeds × tasks (the group's task order), success in %.
    pub scores: Vec<Vec<f64>>,
    /// rliable `aggregate_iqm` and `aggregate_mean` of `scores` with their stratified bootstrap
    /// intervals (strata = tasks).
    pub iqm: Ci,
    pub mean: Ci,
    /// Sample std (n − 1) over seeds of each seed's mean over tasks.
    pub std: f64,
    /// The fewest and most evaluations a run contributed (1 for [`FinalKind::FinalEval`]; for
    /// [`FinalKind::LastInRun`] up to `last_evals`), and the env steps those evaluations span
    /// over the group's runs.
    pub evals_used: (usize, usize),
    pub env_steps: (u64, u64),
    pub episodes_per_task: usize,
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
    /// The runs' networks (distinct labels, joined by ` / `).
    pub networks: String,
    /// Runs of the group without `eval-final.json` (their last in-run evaluation is final).
    pub without_final_eval: Vec<PathBuf>,
    /// The statistics with final = the run's last evaluation (`eval-final.json`).
    pub final_eval: Option<FinalStats>,
    /// The statistics with final = the mean of the last in-run evaluations (none when no run
    /// of the group has any, as for zero-shot evaluation folders).
    pub last_in_run: Option<FinalStats>,
}

/// The probability that algorithm `x` improves on `y` in one experiment (rliable
/// `probability_of_improvement`, intervals by its `StratifiedIndependentBootstrap`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Comparison {
    pub experiment: String,
    pub x: String,
    pub y: String,
    /// P(X > Y) with final = `eval-final.json`, and with final = the last in-run evaluations
    /// (none when either group lacks that definition).
    pub final_eval: Option<Ci>,
    pub last_in_run: Option<Ci>,
}

/// Everything `results.md` and `results.json` summarize.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    pub groups: Vec<GroupSummary>,
    pub comparisons: Vec<Comparison>,
    /// `last_evals`, bootstrap resamples, coverage and seed, as used.
    pub last_evals: usize,
    pub bootstrap_reps: usize,
    pub confidence: f64,
    pub bootstrap_seed: u64,
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

/// seed → task → final success (%) of a group under `kind`, with the runs' contributing
/// evaluations. A task scored twice for one seed is an error.
struct SeedScores {
    by_seed: BTreeMap<u64, BTreeMap<String, f64>>,
    /// The evaluations behind the scores (one per run for `FinalEval`, the last few for
    /// `LastInRun`), and per run how many were averaged.
    points: Vec<EvalPoint>,
    evals_per_run: Vec<usize>,
}

fn seed_scores(
    experiment: &str,
    algorithm: &str,
    members: &[&RunEval],
    kind: FinalKind,
    last_evals: usize,
) -> Result<SeedScores> {
    let mut out = SeedScores {
        by_seed: BTreeMap::new(),
        points: Vec::new(),
        evals_per_run: Vec::new(),
    };
    for m in members {
        let used: &[EvalPoint] = match kind {
            FinalKind::FinalEval => m.points.last().map_or(&[], std::slice::from_ref),
            FinalKind::LastInRun => &m.in_run[m.in_run.len().saturating_sub(last_evals)..],
        };
        if used.is_empty() {
            continue;
        }
        out.points.extend(used.iter().cloned());
        out.evals_per_run.push(used.len());
        let seed = out.by_seed.entry(m.seed).or_default();
        for (k, t) in m.tasks.iter().enumerate() {
            let v = used.iter().map(|p| p.per_task_success[k]).sum::<f64>() / used.len() as f64;
            anyhow::ensure!(
                seed.insert(t.clone(), 100.0 * v).is_none(),
                "experiment {experiment} / {algorithm}: seed {} evaluates {t} in two runs (one is {})",
                m.seed,
                m.dir.display()
            );
        }
    }
    Ok(out)
}

/// The seeds × tasks matrix of the seeds that score every task, with those seeds.
fn complete_matrix(
    by_seed: &BTreeMap<u64, BTreeMap<String, f64>>,
    tasks: &[String],
) -> Option<(Vec<u64>, Vec<Vec<f64>>)> {
    let (seeds, rows): (Vec<u64>, Vec<Vec<f64>>) = by_seed
        .iter()
        .filter_map(|(seed, per)| {
            let row: Option<Vec<f64>> = tasks.iter().map(|t| per.get(t).copied()).collect();
            row.map(|r| (*seed, r))
        })
        .unzip();
    (!seeds.is_empty() && !tasks.is_empty()).then_some((seeds, rows))
}

fn final_stats(
    kind: FinalKind,
    scores: &SeedScores,
    tasks: &[String],
    bootstrap: &Bootstrap,
) -> Result<Option<FinalStats>> {
    let Some((seeds, rows)) = complete_matrix(&scores.by_seed, tasks) else {
        return Ok(None);
    };
    let m = ScoreMatrix::from_rows(&rows)?;
    let per_seed: Vec<f64> = rows
        .iter()
        .map(|r| r.iter().sum::<f64>() / r.len() as f64)
        .collect();
    let steps = scores.points.iter().map(|p| p.env_steps);
    Ok(Some(FinalStats {
        kind,
        seeds,
        iqm: bootstrap.iqm(&m)?.into(),
        mean: bootstrap.mean(&m)?.into(),
        std: mean_std(&per_seed).1,
        scores: rows,
        evals_used: (
            scores.evals_per_run.iter().copied().min().unwrap_or(0),
            scores.evals_per_run.iter().copied().max().unwrap_or(0),
        ),
        env_steps: (steps.clone().min().unwrap_or(0), steps.max().unwrap_or(0)),
        episodes_per_task: scores
            .points
            .iter()
            .map(|p| p.episodes_per_task)
            .min()
            .unwrap_or(0),
    }))
}

/// The final-evaluation summary of each group.
///
/// A seed's result is the mean over tasks of its runs' final per-task success: one run per
/// seed for a multi-task experiment (MT10), or one run per task and seed when each task trains
/// alone (MT1-Ind). A task evaluated twice for one seed is an error. The group reports the mean
/// and standard deviation of the seeds' results, and under both definitions of final success
/// the IQM and mean of the seeds × tasks score matrix with stratified bootstrap intervals.
pub fn summarize(runs: &[RunEval], opts: &StatsOptions) -> Result<Vec<GroupSummary>> {
    let mut out = Vec::new();
    for ((experiment, algorithm), members) in group_runs(runs) {
        let mut tasks: Vec<String> = Vec::new();
        for m in &members {
            if m.last().is_some() {
                for t in &m.tasks {
                    if !tasks.contains(t) {
                        tasks.push(t.clone());
                    }
                }
            }
        }
        let finals = seed_scores(
            &experiment,
            &algorithm,
            &members,
            FinalKind::FinalEval,
            opts.last_evals,
        )?;
        let last = seed_scores(
            &experiment,
            &algorithm,
            &members,
            FinalKind::LastInRun,
            opts.last_evals,
        )?;
        let by_seed = &finals.by_seed;
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
        let steps: Vec<u64> = finals.points.iter().map(|p| p.env_steps).collect();
        let mut networks: Vec<&str> = Vec::new();
        for m in &members {
            if !networks.contains(&m.networks.as_str()) {
                networks.push(&m.networks);
            }
        }
        out.push(GroupSummary {
            missing,
            paper_success: paper_success(&experiment, &algorithm)
                .filter(|_| !algorithm.contains('(')),
            seeds: by_seed.keys().copied().collect(),
            runs: members.iter().map(|m| m.dir.clone()).collect(),
            return_mean: mean_std(
                &finals
                    .points
                    .iter()
                    .map(|p| p.mean_return)
                    .collect::<Vec<_>>(),
            )
            .0,
            env_steps: (
                steps.iter().copied().min().unwrap_or(0),
                steps.iter().copied().max().unwrap_or(0),
            ),
            episodes_per_task: finals
                .points
                .iter()
                .map(|p| p.episodes_per_task)
                .min()
                .unwrap_or(0),
            networks: networks.join(" / "),
            without_final_eval: members
                .iter()
                .filter(|m| !m.has_final_eval)
                .map(|m| m.dir.clone())
                .collect(),
            final_eval: final_stats(FinalKind::FinalEval, &finals, &tasks, &opts.bootstrap)?,
            last_in_run: final_stats(FinalKind::LastInRun, &last, &tasks, &opts.bootstrap)?,
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

/// P(X > Y) of `x` over `y` on the tasks of `x` (none when `y` lacks one of them).
fn improvement(
    x: &GroupSummary,
    y: &GroupSummary,
    pick: impl Fn(&GroupSummary) -> Option<&FinalStats>,
    bootstrap: &Bootstrap,
) -> Result<Option<Ci>> {
    let (Some(fx), Some(fy)) = (pick(x), pick(y)) else {
        return Ok(None);
    };
    let columns: Option<Vec<usize>> = x
        .tasks
        .iter()
        .map(|t| y.tasks.iter().position(|u| u == t))
        .collect();
    let Some(columns) = columns.filter(|_| x.tasks.len() == y.tasks.len()) else {
        return Ok(None);
    };
    let mx = ScoreMatrix::from_rows(&fx.scores)?;
    let rows_y: Vec<Vec<f64>> = fy
        .scores
        .iter()
        .map(|r| columns.iter().map(|&c| r[c]).collect())
        .collect();
    let my = ScoreMatrix::from_rows(&rows_y)?;
    Ok(Some(bootstrap.probability_of_improvement(&mx, &my)?.into()))
}

/// Per experiment, every pair of its algorithms `(x, y)` with `x` after `y` in the groups'
/// order (so `terl` over `mtsac`, `(reference)` over `(before)`).
pub fn compare(groups: &[GroupSummary], opts: &StatsOptions) -> Result<Vec<Comparison>> {
    let mut out = Vec::new();
    for (i, y) in groups.iter().enumerate() {
        for x in groups[i + 1..]
            .iter()
            .filter(|x| x.experiment == y.experiment)
        {
            out.push(Comparison {
                experiment: x.experiment.clone(),
                x: x.algorithm.clone(),
                y: y.algorithm.clone(),
                final_eval: improvement(x, y, |g| g.final_eval.as_ref(), &opts.bootstrap)?,
                last_in_run: improvement(x, y, |g| g.last_in_run.as_ref(), &opts.bootstrap)?,
            });
        }
    }
    Ok(out)
}

/// The groups and comparisons of a set of runs.
pub fn summary(runs: &[RunEval], opts: &StatsOptions) -> Result<Summary> {
    let groups = summarize(runs, opts)?;
    let comparisons = compare(&groups, opts)?;
    Ok(Summary {
        groups,
        comparisons,
        last_evals: opts.last_evals,
        bootstrap_reps: opts.bootstrap.reps,
        confidence: opts.bootstrap.confidence,
        bootstrap_seed: opts.bootstrap.seed,
    })
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

fn ci_cell(c: Option<&Ci>, digits: usize) -> String {
    c.map_or_else(|| "—".to_string(), |c| c.label(digits))
}

fn seeds_cell(stats: &FinalStats, g: &GroupSummary) -> String {
    if stats.seeds.len() == g.seeds.len() {
        stats.seeds.len().to_string()
    } else {
        format!("{} of {}", stats.seeds.len(), g.seeds.len())
    }
}

/// `results.md`: Table I with the field's statistics under both definitions of final success,
/// the probabilities of improvement, then a per-task breakdown per experiment.
#[allow(clippy::too_many_lines)] // one table after another, in reading order
pub fn markdown(summary: &Summary) -> String {
    let summaries = &summary.groups;
    let pct = 100.0 * summary.confidence;
    let mut s = String::new();
    let _ = writeln!(s, "# Evaluation results\n");
    let _ = writeln!(
        s,
        "Deterministic evaluations (mean action); success = success at any step of an episode. \
         The statistics follow Agarwal et al. 2021 (rliable): IQM = interquartile mean of the \
         seeds × tasks score matrix, mean = mean over tasks of the mean over seeds, each with a \
         {pct:.0} % stratified percentile-bootstrap interval (strata = tasks, seeds resampled \
         within each task; {} resamples, seed {:#x}); ± = sample std over seeds of each seed's \
         mean over tasks. The paper's Table I reports 5 seeds and 500 trials at its own budget; \
         Meta-World v3 tasks here use v2-style rewards.\n",
        summary.bootstrap_reps, summary.bootstrap_seed
    );
    let _ = writeln!(
        s,
        "## Final success: the final evaluation (`eval-final.json`, all goal variations)\n"
    );
    let _ = writeln!(
        s,
        "| experiment | algorithm | IQM % [{pct:.0} % CI] | mean % [{pct:.0} % CI] | mean ± std | paper % | seeds | eval episodes / task | env steps / run | networks |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    for g in summaries {
        let st = g.final_eval.as_ref();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.1} ± {:.1} | {} | {} | {} | {} | {} |",
            g.experiment,
            g.algorithm,
            ci_cell(st.map(|f| &f.iqm), 1),
            ci_cell(st.map(|f| &f.mean), 1),
            g.success_mean,
            g.success_std,
            g.paper_success
                .map_or_else(|| "—".to_string(), |p| format!("{p:.1}")),
            st.map_or_else(|| g.seeds.len().to_string(), |f| seeds_cell(f, g)),
            g.episodes_per_task,
            steps_label(g.env_steps),
            g.networks
        );
    }
    for g in summaries
        .iter()
        .filter(|g| !g.without_final_eval.is_empty())
    {
        let _ = writeln!(
            s,
            "\n**Note:** {} / {}: {} run(s) without `eval-final.json`; their last in-run evaluation is their final one.",
            g.experiment,
            g.algorithm,
            g.without_final_eval.len()
        );
    }
    let last_k = summary.last_evals;
    let _ = writeln!(
        s,
        "\n## Final success: the mean of the last {last_k} in-run evaluations\n\n\
         Per run and task, the mean success of its last {last_k} in-run evaluations (`eval.mcap` or \
         `progress.jsonl`; fewer when the run has fewer), then the same statistics.\n"
    );
    let _ = writeln!(
        s,
        "| experiment | algorithm | IQM % [{pct:.0} % CI] | mean % [{pct:.0} % CI] | mean ± std | seeds | evaluations / run | eval episodes / task | at env steps |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    let mut none = Vec::new();
    for g in summaries {
        let Some(st) = &g.last_in_run else {
            none.push(format!("{} / {}", g.experiment, g.algorithm));
            continue;
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.1} ± {:.1} | {} | {} | {} | {} |",
            g.experiment,
            g.algorithm,
            st.iqm.label(1),
            st.mean.label(1),
            st.mean.point,
            st.std,
            seeds_cell(st, g),
            if st.evals_used.0 == st.evals_used.1 {
                st.evals_used.0.to_string()
            } else {
                format!("{}–{}", st.evals_used.0, st.evals_used.1)
            },
            st.episodes_per_task,
            steps_label(st.env_steps)
        );
    }
    if !none.is_empty() {
        let _ = writeln!(
            s,
            "\nNo in-run evaluations (evaluation-only folders): {}.",
            none.join(", ")
        );
    }
    if !summary.comparisons.is_empty() {
        let _ = writeln!(
            s,
            "\n## Probability of improvement\n\n\
             P(X > Y): the probability that a seed of X scores higher than a seed of Y on a task \
             (ties count ½), averaged over tasks (rliable `probability_of_improvement`), with its \
             {pct:.0} % stratified bootstrap interval (X and Y resampled independently). 0.5 is no \
             difference.\n"
        );
        let _ = writeln!(
            s,
            "| experiment | X | Y | P(X > Y), final evaluation | P(X > Y), last {last_k} in-run evaluations |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|");
        for c in &summary.comparisons {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                c.experiment,
                c.x,
                c.y,
                ci_cell(c.final_eval.as_ref(), 2),
                ci_cell(c.last_in_run.as_ref(), 2)
            );
        }
    }
    let mut experiments: Vec<&str> = summaries.iter().map(|g| g.experiment.as_str()).collect();
    experiments.dedup();
    for exp in experiments {
        let groups: Vec<&GroupSummary> = summaries.iter().filter(|g| g.experiment == exp).collect();
        let _ = writeln!(
            s,
            "\n## {exp}: per task (final evaluation success %, mean ± std over seeds)\n"
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
                    "\n**Note:** {} seed {seed} has no evaluation of {task}; that seed's mean is over its other tasks, and the IQM and mean leave the seed out.",
                    g.algorithm
                );
            }
        }
        let _ = writeln!(
            s,
            "\nCurves (IQM with its {pct:.0} % stratified bootstrap interval shaded): `{0}-eval-success.png` / `.svg`, `{0}-eval-return.png` / `.svg`.",
            file_stem(exp)
        );
    }
    s
}

fn distinct_seeds(runs: &[&RunEval]) -> usize {
    let mut seeds: Vec<u64> = runs.iter().map(|r| r.seed).collect();
    seeds.sort_unstable();
    seeds.dedup();
    seeds.len()
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
pub fn write_results(
    runs: &[RunEval],
    out_dir: &Path,
    opts: &StatsOptions,
) -> Result<(String, Vec<PathBuf>)> {
    let summary = summary(runs, opts)?;
    let md = markdown(&summary);
    let mut files = Vec::new();
    let md_path = out_dir.join("results.md");
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    files.push(md_path);
    let json_path = out_dir.join("results.json");
    let json = serde_json::json!({
        "groups": summary.groups,
        "comparisons": summary.comparisons,
        "last_evals": summary.last_evals,
        "bootstrap_reps": summary.bootstrap_reps,
        "confidence": summary.confidence,
        "bootstrap_seed": summary.bootstrap_seed,
        "runs": runs,
    });
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
                        &format!("{alg}, {}", seeds_label(distinct_seeds(members))),
                        members,
                        metric,
                        &opts.bootstrap,
                    )
                    .transpose()
                })
                .collect::<Result<_>>()?;
            let (stem, what) = match metric {
                CurveMetric::Success => ("eval-success", "success"),
                CurveMetric::Return => ("eval-return", "return"),
            };
            files.extend(write_chart(
                out_dir,
                &format!("{}-{stem}", file_stem(exp)),
                &format!(
                    "{exp}: deterministic evaluation {what} (IQM, {:.0} % stratified bootstrap CI)",
                    100.0 * opts.bootstrap.confidence
                ),
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
        assert!(
            svg.contains("<svg") && svg.contains("mtsac, 2 seeds") && svg.contains("terl, 1 seed")
        );
        assert_eq!(files.len(), 2 + 4);
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.path().join("results.json")).unwrap(),
        )
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
}
