//! `terl eval --checkpoint PATH [--tasks SET_OR_LIST]`: the deterministic policy of a checkpoint
//! (of `terl train` or of a cluster learner) on each task's 50 goal variations, per-task success
//! rate, mean return and mean first-success step, as a table or one JSON object (`--json`).
//!
//! The protocol, the parallelism and the task encoding of tasks the policy was not trained on
//! (MT-Test zero-shot) are [`terl_runtime::eval`]'s; this file only parses, loads and prints.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use terl_runtime::flags;

use anyhow::{Context, Result};
use clap::Args;
use serde::Serialize;
use terl_runtime::eval::{
    evaluate_policy, load_policy_checkpoint, plan_tasks, EvalSettings, EvalSummary, EvalTask,
    PolicyCheckpoint, UnseenTaskEncoding,
};

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// A checkpoint (`.safetensors` of `terl train` or of a cluster learner), or a run folder
    /// (its newest checkpoint).
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Tasks to evaluate: a task set (mt10, mt50, ml10-train, ml10-test, ml45-train, ml45-test,
    /// mt20, mt1-ind, mt-test; see `terl env list`) or comma-separated names
    /// (default: the tasks the checkpoint was trained on).
    #[arg(long)]
    pub tasks: Option<String>,
    /// Episodes per task; episode k starts from goal variation k mod 50 (default: each of the
    /// 50 variations once, the Meta-World benchmarks' protocol).
    #[arg(long, value_parser = flags::count::<usize>(flags::MAX_EPISODES), default_value_t = terl_sim::metaworld::NUM_VARIATIONS)]
    pub episodes_per_task: usize,
    /// Seed of the goal variations (default: the run's variation_seed, else 0).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Task vector for a task the policy was not trained on: `uniform` (1/num_tasks in every
    /// slot: the average of the trained tasks' conditioning; the default) or `zeros`. A CARE
    /// policy with task-description context takes the task's own description embedding
    /// (`task-embedding`, its default and only setting).
    #[arg(long)]
    pub unseen_task_encoding: Option<UnseenTaskEncoding>,
    /// The task list the checkpoint was trained on, in order (default: from the run's
    /// config.toml next to the checkpoints folder).
    #[arg(long)]
    pub trained_tasks: Option<String>,
    /// Worker threads (default: available parallelism).
    #[arg(long, value_parser = flags::count::<usize>(flags::MAX_THREADS))]
    pub threads: Option<usize>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// The JSON output: where the policy came from, then the evaluation.
#[derive(Debug, Serialize)]
struct EvalOutput {
    checkpoint: String,
    trained_tasks: Vec<&'static str>,
    unseen_task_encoding: UnseenTaskEncoding,
    #[serde(flatten)]
    summary: EvalSummary,
}

/// A checkpoint's policy, the task list it was trained on (one-hot order) and the tasks to run
/// with their task vectors: what `terl eval` and `terl render` share.
pub(crate) struct PolicyAndTasks {
    pub(crate) ckpt: PolicyCheckpoint,
    pub(crate) trained: Vec<&'static str>,
    pub(crate) tasks: Vec<EvalTask>,
    /// What a task outside `trained` is conditioned on (the option, resolved for the policy).
    pub(crate) unseen: UnseenTaskEncoding,
}

impl PolicyAndTasks {
    /// Loads `checkpoint` and checks it against `trained_tasks` (default: the run's
    /// config.toml); `tasks` defaults to the trained tasks; `unseen` to what fits the policy
    /// ([`UnseenTaskEncoding::for_policy`]).
    pub(crate) fn load(
        checkpoint: &std::path::Path,
        trained_tasks: Option<&str>,
        tasks: Option<&str>,
        unseen: Option<UnseenTaskEncoding>,
    ) -> Result<Self> {
        let ckpt = load_policy_checkpoint(checkpoint)?;
        let unseen = UnseenTaskEncoding::for_policy(unseen, &ckpt.sac)?;
        let trained: Vec<&'static str> = match (trained_tasks, ckpt.trained_tasks()) {
            (Some(spec), _) => terl_runtime::resolve_tasks(spec)?,
            (None, Some(tasks)) => tasks?,
            (None, None) => anyhow::bail!(
                "{} is not in a run folder with a config.toml, so the trained task order is \
                 unknown; pass --trained-tasks",
                ckpt.path.display()
            ),
        };
        ckpt.check_trained_tasks(&trained)?;
        let eval_tasks = match tasks {
            Some(spec) => terl_runtime::resolve_tasks(spec)?,
            None => trained.clone(),
        };
        let tasks = plan_tasks(&eval_tasks, &trained, unseen);
        Ok(Self {
            ckpt,
            trained,
            tasks,
            unseen,
        })
    }

    /// The goal variations' seed: `seed`, else the run's `variation_seed`, else 0.
    pub(crate) fn variation_seed(&self, seed: Option<u64>) -> u64 {
        seed.or(self.ckpt.run_config.as_ref().map(|(_, c)| c.variation_seed))
            .unwrap_or(0)
    }
}

pub fn run(args: EvalArgs) -> Result<ExitCode> {
    let loaded = PolicyAndTasks::load(
        &args.checkpoint,
        args.trained_tasks.as_deref(),
        args.tasks.as_deref(),
        args.unseen_task_encoding,
    )?;
    let variation_seed = loaded.variation_seed(args.seed);
    let PolicyAndTasks {
        ckpt,
        trained,
        tasks,
        unseen,
    } = loaded;
    let settings = EvalSettings {
        episodes_per_task: args.episodes_per_task,
        variation_seed,
        threads: args
            .threads
            .unwrap_or_else(|| EvalSettings::default().threads),
        ..EvalSettings::default()
    };
    anyhow::ensure!(settings.threads > 0, "--threads must be at least 1");
    let total = (tasks.len() * settings.episodes_per_task) as u64;
    let bar = if std::io::stderr().is_terminal() {
        let bar = indicatif::ProgressBar::new(total);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} episodes  {elapsed_precise} (eta {eta})",
            )
            .context("progress template")?,
        );
        Some(bar)
    } else {
        None
    };
    let on_episodes = |n: usize| {
        if let Some(b) = &bar {
            b.inc(n as u64);
        }
    };
    let summary = evaluate_policy(&ckpt.policy, &tasks, &settings, &on_episodes, None)?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let out = EvalOutput {
        checkpoint: ckpt.path.display().to_string(),
        trained_tasks: trained,
        unseen_task_encoding: unseen,
        summary,
    };
    if args.json {
        println!("{}", serde_json::to_string(&out)?);
    } else {
        print_table(&out);
    }
    Ok(ExitCode::SUCCESS)
}

fn print_table(o: &EvalOutput) {
    let s = &o.summary;
    println!(
        "checkpoint {}  policy v{}  trained on {} task(s)",
        o.checkpoint,
        s.policy_version,
        o.trained_tasks.len()
    );
    println!(
        "deterministic policy (tanh of the mean), {} episode(s) per task over the 50 goal \
         variations of seed {}; {} thread(s), {:.1} s wall{}",
        s.episodes_per_task,
        s.variation_seed,
        s.threads,
        s.wall_seconds,
        s.cpu_seconds
            .map(|c| format!(", {c:.1} s CPU"))
            .unwrap_or_default()
    );
    let mean_label = format!("mean ({} tasks)", s.tasks.len());
    let width = s
        .tasks
        .iter()
        .map(|t| t.task.len())
        .chain([mean_label.len()])
        .max()
        .unwrap_or(4);
    println!(
        "{:<width$}  {:<11}  {:>8}  {:>10}  {:>13}",
        "task", "encoding", "success", "return", "first success"
    );
    for t in &s.tasks {
        let first = t
            .mean_first_success_step
            .map(|f| format!("{f:.1}"))
            .unwrap_or_else(|| "-".into());
        let unstable = if t.unstable_episodes > 0 {
            format!("  ({} unstable)", t.unstable_episodes)
        } else {
            String::new()
        };
        println!(
            "{:<width$}  {:<11}  {:>7.1}%  {:>10.1}  {:>13}{unstable}",
            t.task,
            t.encoding,
            100.0 * t.success_rate,
            t.mean_return,
            first
        );
    }
    println!(
        "{:<width$}  {:<11}  {:>7.1}%  {:>10.1}",
        mean_label,
        "",
        100.0 * s.mean_success_rate,
        s.mean_return
    );
    let unseen: Vec<&str> = s
        .tasks
        .iter()
        .filter(|t| !t.trained)
        .map(|t| t.task.as_str())
        .collect();
    if !unseen.is_empty() {
        println!(
            "zero-shot (not trained on, task vector `{}`): {}",
            o.unseen_task_encoding.as_str(),
            unseen.join(", ")
        );
    }
}
