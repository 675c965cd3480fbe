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

use crate::error::Result;
use crate::metaworld::{Env, ACT_DIM, MAX_PATH_LENGTH};
use crate::vec_env::VecEnv;

/// One task's numbers.
#[derive(Debug, Clone, Serialize)]
pub struct EnvBenchRow {
    pub task: String,
    /// Env steps per second including auto-resets.
    pub env_steps_per_s: f64,
    /// Env steps per second, resets excluded.
    pub env_steps_per_s_no_reset: f64,
    /// Bare physics of the same model: `mj_step` calls per second / frame skip.
    pub physics_steps_per_s: f64,
    /// `env_steps_per_s / physics_steps_per_s` (1.0 = task logic is free).
    pub ratio: f64,
    /// `env_steps_per_s_no_reset / physics_steps_per_s`.
    pub ratio_no_reset: f64,
    /// Mean reset time in milliseconds.
    pub reset_ms: f64,
}

/// Batched stepping.
#[derive(Debug, Clone, Serialize)]
pub struct VecBenchRow {
    pub num_envs: usize,
    /// Env steps per second summed over the batch.
    pub env_steps_per_s: f64,
}

/// The full report printed as JSON.
#[derive(Debug, Clone, Serialize)]
pub struct EnvBenchReport {
    pub seconds_per_measurement: f64,
    pub tasks: Vec<EnvBenchRow>,
    pub min_ratio: f64,
    pub vec_env: Vec<VecBenchRow>,
    /// Per-step throughput of E = 8 over E = 1 (≥ 1 means batching costs nothing).
    pub vec_env_8_over_1: f64,
}

fn random_actions(seed: u64, n: usize) -> Vec<[f32; ACT_DIM]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0)))
        .collect()
}

/// Runs `f` on an alternating schedule until `budget` is spent, returns (count, busy time).
fn measure_env(task: &str, budget: Duration, actions: &[[f32; ACT_DIM]]) -> Result<EnvBenchRow> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // Environment path: step + observation + reward, auto-reset at truncation.
    let mut env = Env::new(task)?;
    env.reset_random(&mut rng)?;
    let (mut steps, mut resets) = (0u64, 0u64);
    let (mut step_time, mut reset_time) = (Duration::ZERO, Duration::ZERO);
    let start = Instant::now();
    while start.elapsed() < budget {
        let t0 = Instant::now();
        for _ in 0..50 {
            let out = env.step(&actions[(steps as usize) % actions.len()])?;
            steps += 1;
            if out.truncated {
                let t1 = Instant::now();
                env.reset_random(&mut rng)?;
                reset_time += t1.elapsed();
                resets += 1;
            }
        }
        step_time += t0.elapsed();
    }
    let with_reset = steps as f64 / step_time.as_secs_f64();
    let no_reset = steps as f64 / (step_time - reset_time).as_secs_f64();

    // Physics bound: the same model and actions, nothing else (resets untimed).
    let mut phys = Env::new(task)?;
    phys.reset_random(&mut rng)?;
    let mut n = 0u64;
    let mut busy = Duration::ZERO;
    let start = Instant::now();
    while start.elapsed() < budget {
        let t0 = Instant::now();
        for k in 0..MAX_PATH_LENGTH as usize {
            phys.physics_only_step(&actions[(n as usize + k) % actions.len()]);
        }
        busy += t0.elapsed();
        n += u64::from(MAX_PATH_LENGTH);
        phys.reset_random(&mut rng)?;
    }
    let physics = n as f64 / busy.as_secs_f64();
    Ok(EnvBenchRow {
        task: env.name().to_string(),
        env_steps_per_s: with_reset,
        env_steps_per_s_no_reset: no_reset,
        physics_steps_per_s: physics,
        ratio: with_reset / physics,
        ratio_no_reset: no_reset / physics,
        reset_ms: if resets > 0 {
            reset_time.as_secs_f64() * 1e3 / resets as f64
        } else {
            f64::NAN
        },
    })
}

fn measure_vec(tasks: &[&str], num_envs: usize, budget: Duration) -> Result<VecBenchRow> {
    let mut v = VecEnv::round_robin(tasks, num_envs, 3)?;
    let actions: Vec<f32> = random_actions(11, 1024 * num_envs)
        .into_iter()
        .flatten()
        .collect();
    let stride = num_envs * ACT_DIM;
    let batches = actions.len() / stride;
    let mut k = 0usize;
    let start = Instant::now();
    while start.elapsed() < budget {
        v.step(&actions[(k % batches) * stride..(k % batches + 1) * stride])?;
        k += 1;
    }
    Ok(VecBenchRow {
        num_envs,
        env_steps_per_s: (k * num_envs) as f64 / start.elapsed().as_secs_f64(),
    })
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
    let one = measure_vec(tasks, 1, budget)?;
    let eight = measure_vec(tasks, 8, budget)?;
    Ok(EnvBenchReport {
        seconds_per_measurement: seconds,
        min_ratio,
        vec_env_8_over_1: eight.env_steps_per_s / one.env_steps_per_s,
        vec_env: vec![one, eight],
        tasks: rows,
    })
}
