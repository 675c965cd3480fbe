//! The statistics of `terl report` over runs: runs are grouped by experiment (the run file's
//! `experiment`, else its `tasks`) and algorithm. Each group's final success is a seeds × tasks
//! score matrix (%), under two definitions: the run's final evaluation (`eval-final.json`), and
//! per task the mean of its last few in-run evaluations ([`StatsOptions::last_evals`]). Of each
//! matrix the group reports the IQM and the mean with stratified bootstrap intervals
//! ([`terl_stats`], as rliable), the mean ± standard deviation over seeds of each seed's mean
//! over tasks (sample std, n − 1; 0 for one seed), with the number of seeds, evaluation
//! episodes per task, env steps and networks, next to the paper's Table I; and for two
//! algorithms of an experiment the probability of improvement with its interval.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Result;
use serde::Serialize;
use terl_stats::{Bootstrap, Interval, ScoreMatrix};

use super::runs::{EvalPoint, RunEval};

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
    pub(super) fn label(&self, digits: usize) -> String {
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
    #[serde(serialize_with = "super::runs::lossy_paths")]
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
    #[serde(serialize_with = "super::runs::lossy_paths")]
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
