//! `terl planner eval --planner P --dataset HELDOUT.mcap... [--rollouts K] [--json]`:
//!
//! (a) **F against the true step gap** on pairs `(s_t, s_{t+k}, a_t)` from each held-out
//! trajectory up to its first success ([`terl_rl::planner_eval`]): Spearman ρ overall and per
//! task, median `|F − k| / k` in bins of `k`.
//!
//! (b) **AN alone in the real environment**: for `K` held-out trajectories per task (those that
//! record their goal variation), the environment is reset to the same variation (the same start
//! state) and AN acts for up to 500 steps toward a goal state from one of two sources:
//! - `final-state` ([`terl_rl::guidance::GoalSource::FinalState`]): the last state (at success)
//!   of the successful trajectory of the same task in the goal library (`--goals`, default the
//!   held-out datasets) whose goal position `obs[36..39]` is nearest to this episode's, never one
//!   of the same variation, with the goal and the object (reach: hand) position set to this
//!   episode's goal ([`GoalLibrary::goal_into`], what the actor does); fixed for the episode;
//! - `replace`: the current observation with the object's (reach: the hand's) position replaced
//!   by the goal position in both frames, rebuilt every step (the guidance of the committed runs).
//!
//! Success is Meta-World's flag at any step (the benchmarks' rule); the final distance is that of
//! the object (reach: the hand) to the goal position after the last step. Uniform random actions
//! on the same variations are the baseline.

use std::path::PathBuf;
use std::process::ExitCode;
use terl_runtime::flags;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use terl_nn::par_for_threads;
use terl_rl::guidance::{goal_state_into, GoalLibrary, GoalTarget, GOAL_POS};
use terl_rl::planner_eval::{predict_gaps, score, ReachScore};
use terl_rl::{Planner, Tep};
use terl_sim::{Env, ACTION_DIM, OBS_DIM};

use super::files::{check_output, planner_from, read_trajectories, split_held_out, Trajectory};
use super::train::held_out_pairs;

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// The planner file (`terl planner train --out`, or `checkpoints/planner.safetensors`).
    #[arg(long)]
    pub planner: PathBuf,
    /// Held-out TEP datasets (repeatable).
    #[arg(long = "dataset", required = true)]
    pub datasets: Vec<PathBuf>,
    /// Score only the first K trajectories of each task of `--dataset` (the ones `terl planner
    /// train --hold-out-trajectories K` left out); 0: every trajectory.
    #[arg(long, value_parser = flags::count_or_zero::<usize>(flags::MAX_HOLD_OUT), default_value_t = 0, value_name = "K")]
    pub hold_out_trajectories: usize,
    /// AN episodes per task in the real environment (0: only the F check).
    #[arg(long, value_parser = flags::count_or_zero::<usize>(flags::MAX_EPISODES), default_value_t = 10)]
    pub rollouts: usize,
    /// Goal sources of the AN episodes.
    #[arg(long, value_enum, default_value = "both")]
    pub goal_source: GoalSourceArg,
    /// Datasets of successful trajectories the `final-state` goals come from (default: the
    /// held-out datasets; a trajectory of the episode's own variation is never used).
    #[arg(long = "goals")]
    pub goals: Vec<PathBuf>,
    /// Seed of the goal-variation list the datasets were made with.
    #[arg(long, default_value_t = 0)]
    pub variation_seed: u64,
    /// Pairs per held-out trajectory for the F check (a uniform sample when it has more).
    #[arg(long, value_parser = flags::count::<usize>(flags::MAX_PAIRS), default_value_t = 200)]
    pub pairs_per_trajectory: usize,
    /// Seed of the pair sample and the random actions.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    pub json: bool,
    /// Also write the JSON object to this file (the tables still go to standard output).
    #[arg(long)]
    pub json_out: Option<PathBuf>,
    /// Use damaged or incomplete datasets up to their damage (default: refuse them).
    #[arg(long)]
    pub accept_partial: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum GoalSourceArg {
    FinalState,
    Replace,
    Both,
}

/// One arm's result on one task.
#[derive(Debug, Default, Serialize)]
struct Arm {
    episodes: usize,
    successes: usize,
    success_rate: f64,
    /// Mean over episodes of the final object (reach: hand) to goal distance, metres.
    final_distance_mean: f64,
}

impl Arm {
    fn add(&mut self, success: bool, distance: f64) {
        self.episodes += 1;
        self.successes += success as usize;
        self.final_distance_mean += distance;
    }

    fn finish(&mut self) {
        if self.episodes > 0 {
            self.success_rate = self.successes as f64 / self.episodes as f64;
            self.final_distance_mean /= self.episodes as f64;
        }
    }
}

#[derive(Debug, Serialize)]
struct TaskReport {
    task: String,
    trajectories: usize,
    f: ReachScore,
    #[serde(skip_serializing_if = "Option::is_none")]
    an_final_state: Option<Arm>,
    #[serde(skip_serializing_if = "Option::is_none")]
    an_replace: Option<Arm>,
    #[serde(skip_serializing_if = "Option::is_none")]
    random: Option<Arm>,
}

#[derive(Debug, Serialize)]
struct Report {
    planner: String,
    planner_updates: String,
    datasets: Vec<String>,
    f: ReachScore,
    tasks: Vec<TaskReport>,
}

/// The successful trajectories of one task as goal candidates: (variation, final state).
type GoalCandidates = Vec<(Option<u32>, Vec<f32>)>;

fn candidates(trajectories: &[Trajectory], task: &str) -> GoalCandidates {
    trajectories
        .iter()
        .filter(|t| t.task == task && t.succeeded() && t.contiguous())
        .map(|t| (t.variation, t.next_obs_at(t.until_success() - 1).to_vec()))
        .collect()
}

/// The goal of [`terl_rl::guidance::GoalSource::FinalState`] for an episode of variation `variation` starting at
/// `start`: [`GoalLibrary::goal_into`] (the actor's own selection) over the candidates of other
/// variations.
fn final_state_goal(cands: &GoalCandidates, start: &[f32], variation: u32) -> Option<Vec<f32>> {
    let mut lib = GoalLibrary::new(OBS_DIM);
    for (v, s) in cands {
        if *v != Some(variation) {
            lib.push(0, s);
        }
    }
    let mut g = vec![0.0; OBS_DIM];
    lib.goal_into(0, start, &mut g).then_some(g)
}

enum Actor<'a> {
    FinalState(&'a [f32]),
    Replace(GoalTarget),
    Random,
}

/// One episode from variation `variation`: (success, final distance).
fn rollout(
    env: &mut Env,
    planner: &mut Planner,
    actor: Actor<'_>,
    variation_seed: u64,
    variation: u32,
    rng: &mut ChaCha8Rng,
) -> Result<(bool, f64)> {
    let target = GoalTarget::for_task(env.name());
    let mut obs64 = env.reset_variation(variation_seed, variation as usize)?;
    let mut goal = [0.0f32; OBS_DIM];
    let mut action = [0.0f32; ACTION_DIM];
    let mut success = false;
    loop {
        let obs: [f32; OBS_DIM] = obs64.map(|v| v as f32);
        match actor {
            Actor::FinalState(g) => planner.actions(&obs, g, &mut action),
            Actor::Replace(t) => {
                goal_state_into(&obs, t, &mut goal);
                planner.actions(&obs, &goal, &mut action);
            }
            Actor::Random => {
                for a in &mut action {
                    *a = rng.gen_range(-1.0..=1.0);
                }
            }
        }
        let s = env.step(&action)?;
        success |= s.success;
        obs64 = s.obs;
        if s.truncated || s.unstable || success {
            break;
        }
    }
    let pos = &obs64[target.range()];
    let distance = pos
        .iter()
        .zip(&obs64[GOAL_POS])
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt();
    Ok((success, distance))
}

/// The AN episodes of one task.
fn task_rollouts(
    task: &str,
    held_out: &[&Trajectory],
    lib: &GoalCandidates,
    tep: &Tep<f32>,
    args: &EvalArgs,
) -> Result<[Option<Arm>; 3]> {
    let mut env = Env::new(task)?;
    let mut planner = tep.planner(1);
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0xa11ce);
    let mut want_final = args.goal_source != GoalSourceArg::Replace;
    if want_final && lib.is_empty() {
        // Selected data of a task the policy rarely solves may hold no success yet.
        eprintln!(
            "[planner eval] {task}: no successful trajectory to take final-state goals from; \
             that arm is left out"
        );
        want_final = false;
    }
    let want_replace = args.goal_source != GoalSourceArg::FinalState;
    let (mut fin, mut rep, mut rnd) = (Arm::default(), Arm::default(), Arm::default());
    let with_variation: Vec<u32> = held_out.iter().filter_map(|t| t.variation).collect();
    anyhow::ensure!(
        !with_variation.is_empty(),
        "{task}: no held-out trajectory records its goal variation (datasets of runs made \
         before episodes carried it do not); use --rollouts 0 for the F check only"
    );
    for e in 0..args.rollouts {
        let v = with_variation[e % with_variation.len()];
        let start = env.reset_variation(args.variation_seed, v as usize)?;
        let start: Vec<f32> = start.iter().map(|&x| x as f32).collect();
        // An episode whose variation is the only one with a success has no goal of another
        // variation: left out of that arm.
        if let Some(g) = want_final
            .then(|| final_state_goal(lib, &start, v))
            .flatten()
        {
            let (s, d) = rollout(
                &mut env,
                &mut planner,
                Actor::FinalState(&g),
                args.variation_seed,
                v,
                &mut rng,
            )?;
            fin.add(s, d);
        }
        if want_replace {
            let t = GoalTarget::for_task(task);
            let (s, d) = rollout(
                &mut env,
                &mut planner,
                Actor::Replace(t),
                args.variation_seed,
                v,
                &mut rng,
            )?;
            rep.add(s, d);
        }
        let (s, d) = rollout(
            &mut env,
            &mut planner,
            Actor::Random,
            args.variation_seed,
            v,
            &mut rng,
        )?;
        rnd.add(s, d);
    }
    for a in [&mut fin, &mut rep, &mut rnd] {
        a.finish();
    }
    // An arm that ran no episode has no result (not 0 %).
    Ok([
        (want_final && fin.episodes > 0).then_some(fin),
        want_replace.then_some(rep),
        Some(rnd),
    ])
}

pub fn run(args: EvalArgs) -> Result<ExitCode> {
    if let Some(path) = &args.json_out {
        let mut inputs: Vec<&std::path::Path> = vec![args.planner.as_path()];
        inputs.extend(
            args.datasets
                .iter()
                .chain(&args.goals)
                .map(PathBuf::as_path),
        );
        check_output(path, "--json-out", &inputs)?;
    }
    anyhow::ensure!(
        args.pairs_per_trajectory > 0,
        "--pairs-per-trajectory must be ≥ 1"
    );
    // One read of the planner file: the weights evaluated and the update count reported come
    // from the same bytes, even if the file is replaced meanwhile (a live run's planner).
    let file = terl_nn::tensors::TensorFile::load(&args.planner)
        .with_context(|| format!("cannot read the planner file {}", args.planner.display()))?;
    let tep = planner_from(&file, &args.planner)?;
    let mut held_out = read_trajectories(&args.datasets, args.accept_partial)?;
    if args.hold_out_trajectories > 0 {
        held_out = split_held_out(held_out, args.hold_out_trajectories).1;
    }
    let goals = if args.goals.is_empty() {
        held_out.clone()
    } else {
        read_trajectories(&args.goals, args.accept_partial)?
    };
    let mut tasks: Vec<String> = Vec::new();
    let pairs = held_out_pairs(&held_out, &mut tasks, args.pairs_per_trajectory, args.seed);
    anyhow::ensure!(
        !pairs.is_empty(),
        "the held-out datasets have no trajectory to take pairs from"
    );
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let pred = predict_gaps(&tep, &pairs, par_for_threads(threads));
    let overall = score(&pred, &pairs.gaps);
    let per_task_f: Vec<ReachScore> = (0..tasks.len())
        .map(|k| {
            let (p, g): (Vec<f64>, Vec<u32>) = pred
                .iter()
                .zip(&pairs.gaps)
                .zip(&pairs.tasks)
                .filter(|(_, &t)| t == k)
                .map(|((&p, &g), _)| (p, g))
                .unzip();
            score(&p, &g)
        })
        .collect();
    // AN episodes, tasks spread over the cores.
    let rollouts: Vec<Result<[Option<Arm>; 3]>> = if args.rollouts == 0 {
        tasks.iter().map(|_| Ok([None, None, None])).collect()
    } else {
        std::thread::scope(|scope| {
            let handles: Vec<_> = (0..threads)
                .map(|w| {
                    let (tasks, held_out, goals, tep, args) =
                        (&tasks, &held_out, &goals, &tep, &args);
                    scope.spawn(move || {
                        (w..tasks.len())
                            .step_by(threads)
                            .map(|k| {
                                let task = &tasks[k];
                                let mine: Vec<&Trajectory> =
                                    held_out.iter().filter(|t| t.task == *task).collect();
                                let lib = candidates(goals, task);
                                (k, task_rollouts(task, &mine, &lib, tep, args))
                            })
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            let mut all: Vec<(usize, Result<[Option<Arm>; 3]>)> = handles
                .into_iter()
                .flat_map(|h| h.join().expect("rollout worker panicked"))
                .collect();
            all.sort_by_key(|(k, _)| *k);
            all.into_iter().map(|(_, r)| r).collect()
        })
    };
    let mut reports = Vec::new();
    for ((task, f), r) in tasks.iter().zip(per_task_f).zip(rollouts) {
        let [an_final_state, an_replace, random] = r?;
        reports.push(TaskReport {
            task: task.clone(),
            trajectories: held_out.iter().filter(|t| t.task == *task).count(),
            f,
            an_final_state,
            an_replace,
            random,
        });
    }
    let report = Report {
        planner: args.planner.display().to_string(),
        planner_updates: file
            .metadata
            .get("terl.tep_updates")
            .cloned()
            .unwrap_or_default(),
        datasets: args
            .datasets
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        f: overall,
        tasks: reports,
    };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_tables(&report);
    }
    if let Some(path) = &args.json_out {
        // After the tables, so a failed write loses nothing that was printed.
        let partial = super::files::partial_path(path);
        std::fs::write(&partial, serde_json::to_string_pretty(&report)? + "\n")
            .and_then(|()| std::fs::rename(&partial, path))
            .with_context(|| format!("cannot write {}", path.display()))
            .inspect_err(|_| {
                let _ = std::fs::remove_file(&partial);
            })?;
    }
    Ok(ExitCode::SUCCESS)
}

fn pct(a: &Option<Arm>) -> String {
    a.as_ref()
        .map(|a| {
            format!(
                "{:.0} % ({:.3})",
                100.0 * a.success_rate,
                a.final_distance_mean
            )
        })
        .unwrap_or_else(|| "–".into())
}

fn print_tables(r: &Report) {
    println!(
        "planner {} ({} updates) on {}",
        r.planner,
        r.planner_updates,
        r.datasets.join(", ")
    );
    println!();
    println!("F against the true step gap k (pairs up to each trajectory's first success)");
    println!(
        "{:<26} {:>7} {:>7} {:>12} {:>12} {:>12} {:>12}",
        "task", "pairs", "ρ", "err k 1–10", "err 11–30", "err 31–100", "err >100"
    );
    let row = |name: &str, s: &ReachScore| {
        let b = |i: usize| {
            let x = s.bins[i].median_relative_error;
            if x.is_nan() {
                "–".to_string()
            } else {
                format!("{:.0} %", 100.0 * x)
            }
        };
        println!(
            "{:<26} {:>7} {:>7.3} {:>12} {:>12} {:>12} {:>12}",
            name,
            s.pairs,
            s.spearman,
            b(0),
            b(1),
            b(2),
            b(3)
        );
    };
    for t in &r.tasks {
        row(&t.task, &t.f);
    }
    row("all", &r.f);
    if r.tasks.iter().any(|t| t.random.is_some()) {
        println!();
        println!("AN alone in the environment: success (mean final distance to the goal, m)");
        println!(
            "{:<26} {:>9} {:>18} {:>18} {:>18}",
            "task", "episodes", "AN final-state", "AN replace", "random"
        );
        for t in &r.tasks {
            let n = t.random.as_ref().map_or(0, |a| a.episodes);
            println!(
                "{:<26} {:>9} {:>18} {:>18} {:>18}",
                t.task,
                n,
                pct(&t.an_final_state),
                pct(&t.an_replace),
                pct(&t.random)
            );
        }
    }
}
