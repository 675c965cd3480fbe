//! Run folders as evaluation results: what `terl report` reads from each run (its run file,
//! `progress.jsonl`, `eval.mcap`, `eval-final.json`), checked against the run's own config.
//!
//! A run folder contributes its **deterministic evaluations** (the policy's mean action on
//! each task's goal variations), never its training episodes:
//! - `progress.jsonl` of `terl train` (one line per evaluation, with the env steps);
//! - the in-run evaluations of a cluster run (`eval.mcap`, written by the selector);
//! - `eval-final.json`, a `terl eval --json` of the final checkpoint (all 50 goal variations
//!   per task), which is then the run's final point.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::Serialize;
use terl_runtime::RunConfig;

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

/// A path as JSON text, lossily where it is not UTF-8 (serde refuses such a path).
fn lossy_path<S: serde::Serializer>(path: &Path, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&path.to_string_lossy())
}

/// Paths as JSON text, each as [`lossy_path`].
pub(super) fn lossy_paths<S: serde::Serializer>(
    paths: &[PathBuf],
    s: S,
) -> Result<S::Ok, S::Error> {
    s.collect_seq(paths.iter().map(|p| p.to_string_lossy()))
}

/// The evaluations of one run folder.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RunEval {
    /// The run folder (in results.json as text; a name that is not UTF-8 is written lossily).
    #[serde(serialize_with = "lossy_path")]
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
        // Evaluations without the run file that says what they measured (a run whose
        // services were started one by one, not by the launcher, has none) cannot enter a
        // table; they are named so that nobody takes them for an empty folder.
        let mut found: Vec<String> = [FINAL_EVAL, "progress.jsonl"]
            .into_iter()
            .filter(|f| std::fs::symlink_metadata(dir.join(f)).is_ok())
            .map(String::from)
            .collect();
        let eval_segments = terl_telemetry::existing_paths(dir, "eval")
            .into_iter()
            .chain(terl_telemetry::unread_segments(dir, "eval"));
        found.extend(
            eval_segments.filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned())),
        );
        let why = if found.is_empty() {
            format!("{} is not a run folder (no config.toml)", dir.display())
        } else {
            format!(
                "{} has evaluations ({}) but no config.toml, the run file that names their \
                 tasks and algorithm (the launcher writes it; give the run's file there to \
                 report them)",
                dir.display(),
                found.join(", ")
            )
        };
        return Err(NoEvaluations(why).into());
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
    let eval_log = terl_telemetry::read_run_log::<terl_wire::EvalResult>(dir, "eval")?;
    for note in eval_log.notes() {
        eprintln!("{note}");
    }
    let evals = eval_log.records;
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
#[allow(clippy::too_many_lines)] // one check per field of eval-final.json, in file order
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
