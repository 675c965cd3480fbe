//! `terl planner dataset --tasks SET --episodes-per-task N --policy scripted [--noise σ]
//! [--variations RANGE] --out D.mcap`: trajectories in the TEP dataset format (the selector's
//! MCAP, `terl.v1.TepSample`), from Meta-World's scripted policies (`crates/sim`'s
//! `metaworld::policies`, ported from `metaworld/policies/*.py`) with Gaussian action noise, as
//! Meta-World's own policy tests run them (`action + N(0, σ²)`, clipped to [−1, 1]).
//!
//! Episode `e` of a task starts from goal variation `variations[e mod len]` of the task's 50
//! (`--variation-seed`, the same list `terl eval` and the cluster use), so a training set and a
//! held-out set are two disjoint ranges. Each sample records the step's success flag and the
//! variation; an episode ends `--after-success` steps after its first success (default: at it)
//! or at Meta-World's 500-step limit. Episodes that never succeed are dropped unless
//! `--keep-failures` (a planner dataset is the paper's "selected successful trajectories").

use std::path::PathBuf;
use std::process::ExitCode;
use terl_runtime::flags;

use anyhow::{Context, Result};
use clap::Args;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use terl_sim::metaworld::{policies, NUM_VARIATIONS};
use terl_sim::{Env, ACTION_DIM};
use terl_telemetry::TepDatasetWriter;
use terl_wire::TepSample;

#[derive(Debug, Args)]
pub struct DatasetArgs {
    /// Tasks: a task set (mt10, mt1-ind, …; see `terl env list`) or comma-separated names.
    #[arg(long)]
    pub tasks: String,
    /// Episodes per task.
    #[arg(long, value_parser = flags::count::<usize>(MAX_EPISODES_PER_TASK as u64), default_value_t = 200)]
    pub episodes_per_task: usize,
    /// Where the actions come from: `scripted` (Meta-World's scripted policies).
    #[arg(long, default_value = "scripted")]
    pub policy: String,
    /// Standard deviation of the Gaussian noise added to each action component.
    #[arg(long, value_parser = flags::parse_scale, default_value_t = 0.1)]
    pub noise: f64,
    /// Goal variations to start from: a range `A..B` (B excluded) or a comma-separated list of
    /// indices in 0..50.
    #[arg(long, default_value = "0..50")]
    pub variations: String,
    /// Seed of the goal-variation list (as `terl eval --seed` and the run file's variation_seed).
    #[arg(long, default_value_t = 0)]
    pub variation_seed: u64,
    /// Steps kept after the first success.
    #[arg(long, value_parser = flags::count_or_zero::<u32>(u64::from(terl_sim::metaworld::MAX_PATH_LENGTH)), default_value_t = 0)]
    pub after_success: u32,
    /// Keep episodes that never succeed.
    #[arg(long)]
    pub keep_failures: bool,
    /// Seed of the action noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The dataset to write (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Parses `A..B` or `i,j,k` into variation indices (each below 50, no repeats).
pub fn parse_variations(spec: &str) -> Result<Vec<usize>> {
    let spec = spec.trim();
    let out: Vec<usize> = if let Some((a, b)) = spec.split_once("..") {
        let a: usize = a
            .trim()
            .parse()
            .with_context(|| format!("variations {spec:?}"))?;
        let b: usize = b
            .trim()
            .parse()
            .with_context(|| format!("variations {spec:?}"))?;
        anyhow::ensure!(a < b, "variations {spec:?}: an empty range");
        anyhow::ensure!(
            b <= NUM_VARIATIONS,
            "variations {spec:?}: Meta-World has goal variations 0..{NUM_VARIATIONS}"
        );
        (a..b).collect()
    } else {
        spec.split(',')
            .map(|p| {
                p.trim()
                    .parse::<usize>()
                    .with_context(|| format!("variations {spec:?}: {p:?} is not an index"))
            })
            .collect::<Result<_>>()?
    };
    anyhow::ensure!(!out.is_empty(), "variations {spec:?}: none given");
    if let Some(bad) = out.iter().find(|&&v| v >= NUM_VARIATIONS) {
        anyhow::bail!("variation {bad} is not in 0..{NUM_VARIATIONS}");
    }
    let mut sorted = out.clone();
    sorted.sort_unstable();
    sorted.dedup();
    anyhow::ensure!(
        sorted.len() == out.len(),
        "variations {spec:?}: an index twice"
    );
    Ok(out)
}

/// What one task contributed.
#[derive(Debug, Serialize)]
struct TaskSummary {
    task: String,
    episodes: usize,
    successes: usize,
    kept: usize,
    transitions: usize,
    /// Mean steps to the first success over the successful episodes.
    mean_steps_to_success: f64,
}

/// One episode's samples and whether it succeeded.
fn episode(
    env: &mut Env,
    policy: policies::Policy,
    args: &DatasetArgs,
    variation: usize,
    rng: &mut ChaCha8Rng,
    trajectory_id: u64,
) -> Result<(Vec<TepSample>, Option<u32>)> {
    let (noise, after_success) = (args.noise, args.after_success);
    let mut obs = env.reset_variation(args.variation_seed, variation)?;
    let mut z = [0.0f64; ACTION_DIM];
    let mut samples = Vec::new();
    let mut first_success = None;
    for step in 0u32.. {
        let mut action = policy(&obs);
        terl_nn::gaussian::fill_standard_normal(rng, &mut z);
        for (a, n) in action.iter_mut().zip(&z) {
            *a = (f64::from(*a) + noise * n).clamp(-1.0, 1.0) as f32;
        }
        let s = env.step(&action)?;
        samples.push(TepSample {
            task: env.name().to_string(),
            trajectory_id,
            step,
            priority: 0.0,
            obs: obs.map(|v| v as f32),
            next_obs: s.obs.map(|v| v as f32),
            goal_obs: None,
            action,
            success: s.success,
            variation: Some(variation as u32),
        });
        obs = s.obs;
        if s.success && first_success.is_none() {
            first_success = Some(step);
        }
        let done_after_success =
            first_success.is_some_and(|f| step >= f.saturating_add(after_success));
        if s.truncated || s.unstable || done_after_success {
            break;
        }
    }
    Ok((samples, first_success))
}

pub fn run(args: DatasetArgs) -> Result<ExitCode> {
    anyhow::ensure!(
        args.policy == "scripted",
        "--policy {:?}: only `scripted` is supported (a checkpoint's policy gives its own \
         datasets through the cluster's selector: runs/<id>/tep-dataset.mcap)",
        args.policy
    );
    anyhow::ensure!(
        args.noise.is_finite() && args.noise >= 0.0,
        "--noise must be finite and ≥ 0"
    );
    anyhow::ensure!(
        (1..=MAX_EPISODES_PER_TASK).contains(&args.episodes_per_task),
        "--episodes-per-task must be in 1..={MAX_EPISODES_PER_TASK}"
    );
    anyhow::ensure!(
        !args.out.exists(),
        "--out {} already exists; a dataset is never overwritten (remove it or give another path)",
        args.out.display()
    );
    super::files::check_output(&args.out, "--out", &[])?;
    let tasks = terl_runtime::resolve_tasks(&args.tasks)?;
    let variations = parse_variations(&args.variations)?;
    let mut policies_of = Vec::new();
    for t in &tasks {
        policies_of.push(policies::policy(t)?);
    }
    // Written under a marked name and linked to `--out` when complete, so a killed or failed
    // run never leaves a partial dataset at `--out`.
    let partial = super::files::partial_path(&args.out);
    let result = write_dataset(&args, &tasks, &policies_of, &variations, &partial).and_then(
        |(total, summaries)| {
            // A hard link does not replace a file that appeared at `--out` meanwhile.
            std::fs::hard_link(&partial, &args.out)
                .with_context(|| format!("cannot create {}", args.out.display()))?;
            Ok((total, summaries))
        },
    );
    let _ = std::fs::remove_file(&partial);
    let (total, summaries) = result?;
    if args.json {
        println!(
            "{}",
            serde_json::json!({"out": args.out, "transitions": total, "tasks": summaries})
        );
    } else {
        println!(
            "{:<28} {:>8} {:>9} {:>6} {:>11} {:>14}",
            "task", "episodes", "successes", "kept", "transitions", "steps to goal"
        );
        for s in &summaries {
            println!(
                "{:<28} {:>8} {:>9} {:>6} {:>11} {:>14.1}",
                s.task, s.episodes, s.successes, s.kept, s.transitions, s.mean_steps_to_success
            );
        }
        println!("{} transitions written to {}", total, args.out.display());
    }
    Ok(ExitCode::SUCCESS)
}

/// Episodes per task one dataset may hold (each up to 500 transitions).
const MAX_EPISODES_PER_TASK: usize = 100_000;

/// Writes every task's episodes to a new dataset at `path`: the transitions written and each
/// task's summary.
fn write_dataset(
    args: &DatasetArgs,
    tasks: &[&'static str],
    policies_of: &[policies::Policy],
    variations: &[usize],
    path: &std::path::Path,
) -> Result<(u64, Vec<TaskSummary>)> {
    let mut writer = TepDatasetWriter::create(path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    // Episodes are written as they finish and flushed every FLUSH_EVERY episodes, so a killed
    // run's partial file keeps what it completed (readable with `--accept-partial`).
    let log_time = terl_telemetry::unix_nanos();
    let mut summaries = Vec::new();
    for (k, (task, policy)) in tasks.iter().zip(policies_of).enumerate() {
        summaries.push(task_samples(
            k,
            task,
            *policy,
            variations,
            args,
            &mut writer,
            log_time,
        )?);
    }
    anyhow::ensure!(
        summaries.iter().any(|s| s.kept > 0),
        "no episode succeeded, so {} holds no trajectory (--keep-failures keeps them; is \
         --noise {} too large?)",
        args.out.display(),
        args.noise
    );
    let total = writer.finish()?;
    Ok((total, summaries))
}

/// Episodes written between two flushes.
const FLUSH_EVERY: usize = 16;

/// All episodes of task number `k`, written to `writer` as they finish.
fn task_samples(
    k: usize,
    task: &'static str,
    policy: policies::Policy,
    variations: &[usize],
    args: &DatasetArgs,
    writer: &mut TepDatasetWriter,
    log_time: u64,
) -> Result<TaskSummary> {
    let mut env = Env::new(task)?;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ ((k as u64 + 1) << 32));
    let (mut successes, mut kept, mut to_goal, mut transitions) = (0, 0, 0u64, 0);
    for e in 0..args.episodes_per_task {
        let id = ((k as u64) << 32) | e as u64;
        let (samples, first) = episode(
            &mut env,
            policy,
            args,
            variations[e % variations.len()],
            &mut rng,
            id,
        )?;
        if let Some(f) = first {
            successes += 1;
            to_goal += u64::from(f) + 1;
        }
        if first.is_some() || args.keep_failures {
            kept += 1;
            transitions += samples.len();
            for s in &samples {
                writer.write(s, log_time)?;
            }
        }
        if (e + 1) % FLUSH_EVERY == 0 {
            writer.flush()?;
        }
    }
    writer.flush()?;
    Ok(TaskSummary {
        task: task.to_string(),
        episodes: args.episodes_per_task,
        successes,
        kept,
        transitions,
        mean_steps_to_success: if successes > 0 {
            to_goal as f64 / successes as f64
        } else {
            f64::NAN
        },
    })
}
