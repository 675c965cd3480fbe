//! `terl bench env`: environment throughput against the physics bound of the same model.
//!
//! Per task, single thread: env steps/s with random actions and auto-reset (what an actor
//! gets), and in the same run the rate of the bare physics of that model (mocap move +
//! `mj_step` × 5, no observation, reward or reset), whose ratio says how much the task logic
//! costs on top of MuJoCo. Then a `VecEnv` with E = 1 and E = 8 to check batching costs nothing.

use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use terl_sim::metaworld::{goal_variations, Env, ACTION_DIM, MAX_PATH_LENGTH};
use terl_sim::vec_env::VecEnv;
use terl_sim::Result;

/// One task's numbers.
#[derive(Debug, Clone, Serialize)]
pub struct EnvBenchRow {
    /// Meta-World v3 task name.
    pub task: String,
    /// Env steps per second including auto-resets.
    pub env_steps_per_s: f64,
    /// Env steps per second, resets excluded.
    pub env_steps_per_s_no_reset: f64,
    /// Bare physics of the same model: `mj_step` calls per second / frame skip.
    pub physics_steps_per_s: f64,
    /// Env rate over physics rate, median over alternating rounds (1.0 = task logic is free).
    pub ratio: f64,
    /// `env_steps_per_s_no_reset / physics_steps_per_s`.
    pub ratio_no_reset: f64,
    /// Mean reset time in milliseconds.
    pub reset_ms: f64,
}

/// Batched stepping.
#[derive(Debug, Clone, Serialize)]
pub struct VecBenchRow {
    /// Environments in the `VecEnv` (E).
    pub num_envs: usize,
    /// Distinct tasks among the environments.
    pub tasks: usize,
    /// Env steps per second summed over the batch.
    pub env_steps_per_s: f64,
}

/// The full report printed as JSON.
#[derive(Debug, Clone, Serialize)]
pub struct EnvBenchReport {
    /// Seconds each rate was measured for.
    pub seconds_per_measurement: f64,
    /// Per task results, in the order measured.
    pub tasks: Vec<EnvBenchRow>,
    /// Smallest `ratio` over the tasks.
    pub min_ratio: f64,
    /// The goal for every task's `ratio`: task logic costs at most 15 % of the physics rate.
    pub target_ratio: f64,
    /// Tasks whose `ratio` is below `target_ratio`, worst first.
    pub below_target: Vec<String>,
    /// E = 1 and E = 8 on the first task, then E = 8 spread over all tasks.
    pub vec_env: Vec<VecBenchRow>,
    /// Per-step throughput of E = 8 over E = 1 on the same task, median over alternating rounds
    /// (≥ 1: batching costs nothing).
    pub vec_env_8_over_1: f64,
}

fn random_actions(seed: u64, n: usize) -> Vec<[f32; ACTION_DIM]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0)))
        .collect()
}

/// The goal for [`EnvBenchRow::ratio`] on every task.
pub const TARGET_RATIO: f64 = 0.85;

/// Rounds in which the environment and the physics bound are measured alternately, so load
/// from other processes hits both alike; ratios are the median over rounds.
const ROUNDS: usize = 10;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn measure_env(task: &str, budget: Duration, actions: &[[f32; ACTION_DIM]]) -> Result<EnvBenchRow> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // Resets draw from the task's 50 goal variations, as actors do. Each is visited once before
    // timing so the hand-reset cache is in the steady state of a long-running actor.
    let variations = goal_variations(task, 0)?;
    let mut env = Env::new(task)?;
    let mut phys = Env::new(task)?;
    for rv in &variations {
        env.reset(rv)?;
        phys.reset(rv)?;
    }
    let mut pick = || variations[rng.gen_range(0..variations.len())].clone();
    env.reset(&pick())?;
    phys.reset(&pick())?;
    let slice = budget / ROUNDS as u32;
    let (mut steps, mut resets, mut phys_steps) = (0u64, 0u64, 0u64);
    let (mut step_time, mut reset_time, mut phys_time) =
        (Duration::ZERO, Duration::ZERO, Duration::ZERO);
    let (mut ratios, mut ratios_no_reset) = (Vec::new(), Vec::new());
    for _ in 0..ROUNDS {
        // Environment path: step + observation + reward, auto-reset at truncation.
        let (s0, r0, t0) = (steps, reset_time, step_time);
        let start = Instant::now();
        while start.elapsed() < slice {
            let t = Instant::now();
            for _ in 0..50 {
                let out = env.step(&actions[(steps as usize) % actions.len()])?;
                steps += 1;
                if out.truncated {
                    let t1 = Instant::now();
                    env.reset(&pick())?;
                    reset_time += t1.elapsed();
                    resets += 1;
                }
            }
            step_time += t.elapsed();
        }
        let round_steps = (steps - s0) as f64;
        let round_time = (step_time - t0).as_secs_f64();
        let round_reset = (reset_time - r0).as_secs_f64();
        // Physics bound: the same model and actions, nothing else (resets untimed).
        let (p0, pt0) = (phys_steps, phys_time);
        let start = Instant::now();
        while start.elapsed() < slice {
            let t = Instant::now();
            for k in 0..MAX_PATH_LENGTH as usize {
                phys.physics_only_step(&actions[(phys_steps as usize + k) % actions.len()]);
            }
            phys_time += t.elapsed();
            phys_steps += u64::from(MAX_PATH_LENGTH);
            phys.reset(&pick())?;
        }
        let phys_rate = (phys_steps - p0) as f64 / (phys_time - pt0).as_secs_f64();
        ratios.push(round_steps / round_time / phys_rate);
        ratios_no_reset.push(round_steps / (round_time - round_reset) / phys_rate);
    }
    let with_reset = steps as f64 / step_time.as_secs_f64();
    Ok(EnvBenchRow {
        task: env.name().to_string(),
        env_steps_per_s: with_reset,
        env_steps_per_s_no_reset: steps as f64 / (step_time - reset_time).as_secs_f64(),
        physics_steps_per_s: phys_steps as f64 / phys_time.as_secs_f64(),
        ratio: median(ratios),
        ratio_no_reset: median(ratios_no_reset),
        reset_ms: if resets > 0 {
            reset_time.as_secs_f64() * 1e3 / resets as f64
        } else {
            f64::NAN
        },
    })
}

struct VecRun {
    env: VecEnv,
    actions: Vec<f32>,
    k: usize,
    steps: u64,
    time: Duration,
}

impl VecRun {
    fn new(tasks: &[&str], num_envs: usize) -> Result<Self> {
        Ok(Self {
            env: VecEnv::round_robin(tasks, num_envs, 3)?,
            actions: random_actions(11, 1024 * num_envs)
                .into_iter()
                .flatten()
                .collect(),
            k: 0,
            steps: 0,
            time: Duration::ZERO,
        })
    }

    /// Steps for `slice`; returns this slice's env steps per second.
    fn run(&mut self, slice: Duration) -> Result<f64> {
        let n = self.env.num_envs();
        let stride = n * ACTION_DIM;
        let batches = self.actions.len() / stride;
        let (s0, start) = (self.steps, Instant::now());
        while start.elapsed() < slice {
            let b = self.k % batches;
            self.env.step(&self.actions[b * stride..(b + 1) * stride])?;
            self.k += 1;
            self.steps += n as u64;
        }
        let dt = start.elapsed();
        self.time += dt;
        Ok((self.steps - s0) as f64 / dt.as_secs_f64())
    }

    fn row(&self, tasks: usize) -> VecBenchRow {
        VecBenchRow {
            num_envs: self.env.num_envs(),
            tasks,
            env_steps_per_s: self.steps as f64 / self.time.as_secs_f64(),
        }
    }
}

/// Runs the benchmark over `tasks`, `seconds` per measurement.
pub fn env_bench(tasks: &[&str], seconds: f64) -> Result<EnvBenchReport> {
    let budget = Duration::from_secs_f64(seconds);
    let actions = random_actions(5, 4096);
    let rows = tasks
        .iter()
        .map(|t| {
            let row = measure_env(t, budget, &actions)?;
            tracing::info!(task = row.task, ratio = row.ratio, "measured");
            Ok(row)
        })
        .collect::<Result<Vec<_>>>()?;
    let min_ratio = rows.iter().map(|r| r.ratio).fold(f64::INFINITY, f64::min);
    let mut below: Vec<&EnvBenchRow> = rows.iter().filter(|r| r.ratio < TARGET_RATIO).collect();
    below.sort_by(|a, b| a.ratio.total_cmp(&b.ratio));
    let below_target = below.iter().map(|r| r.task.clone()).collect();
    // E = 1 against E = 8 on the same task, alternating.
    let mut one = VecRun::new(&tasks[..1], 1)?;
    let mut eight = VecRun::new(&tasks[..1], 8)?;
    let slice = budget / ROUNDS as u32;
    let mut vec_ratios = Vec::new();
    for _ in 0..ROUNDS {
        let a = one.run(slice)?;
        let b = eight.run(slice)?;
        vec_ratios.push(b / a);
    }
    let mut mixed = VecRun::new(tasks, 8)?;
    mixed.run(budget)?;
    Ok(EnvBenchReport {
        seconds_per_measurement: seconds,
        min_ratio,
        target_ratio: TARGET_RATIO,
        below_target,
        vec_env_8_over_1: median(vec_ratios),
        vec_env: vec![one.row(1), eight.row(1), mixed.row(tasks.len().min(8))],
        tasks: rows,
    })
}
