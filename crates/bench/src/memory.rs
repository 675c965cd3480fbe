//! `terl bench env --memory`: resident memory of Meta-World environments, and the `mjData`
//! arena they use.
//!
//! A probe ([`memory_probe`]) runs in a fresh process (the CLI starts one per measurement, so
//! tasks measured earlier cannot lend their freed pages to later ones). It reads the process's
//! RSS (`VmRSS` of `/proc/self/status`) before any environment exists, after one environment
//! per task, and after `n` per task, every environment reset and stepped with random actions
//! so its data pages are touched as in an actor. MB per additional environment is
//! `(rss_n - rss_1) / (n - 1)`. The same probe rolls out random and scripted episodes and
//! records the peak arena use (`mjData.maxuse_arena`), against which the arena is sized
//! (`terl_sim::metaworld::DEFAULT_ARENA_BYTES`).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use terl_sim::metaworld::{goal_variations, policies, Env, ACTION_DIM, MAX_PATH_LENGTH};
use terl_sim::Result;

/// Floor of the issue: RSS per additional environment of one task, MB.
pub const MAX_MB_PER_ADDITIONAL_ENV: f64 = 5.0;
/// Floor of the issue: RSS of a process with an MT10 actor's 10 environments, MB.
pub const MAX_MT10_SET_MB: f64 = 100.0;

/// Resident set size of this process in MB (10^6 bytes), from `VmRSS` in `/proc/self/status`.
pub fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb * 1024.0 / 1e6)
}

/// What one probe measured.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MemoryProbe {
    /// Meta-World v3 names of the tasks probed together.
    pub tasks: Vec<String>,
    /// Environments per task in the last measurement.
    pub envs_per_task: usize,
    /// RSS before any environment (the process, MuJoCo loaded), MB.
    pub rss_base_mb: f64,
    /// RSS with one environment per task, MB.
    pub rss_one_per_task_mb: f64,
    /// RSS with `envs_per_task` environments per task, MB.
    pub rss_all_mb: f64,
    /// `(rss_all - rss_one_per_task) / (tasks × (envs_per_task - 1))`, MB (none for one env
    /// per task).
    pub mb_per_additional_env: Option<f64>,
    /// `(rss_one_per_task - rss_base) / tasks`: model plus first data, MB.
    pub mb_first_env: f64,
    /// Bytes of the compiled models' buffers (`mjModel.nbuffer`), summed over tasks.
    pub model_buffer_bytes: usize,
    /// Bytes of those buffers returned to the OS (arrays only rendering reads).
    pub model_released_bytes: usize,
    /// Whether all environments of a task hold one model (`Arc::ptr_eq`).
    pub model_shared: bool,
    /// Size of each environment's `mjData` arena, bytes.
    pub arena_bytes: usize,
    /// Peak `mjData.maxuse_arena` over the rollouts, bytes (max over tasks).
    pub arena_peak_bytes: usize,
    /// Peak contacts over the rollouts (`mjData.maxuse_con`).
    pub peak_contacts: usize,
    /// Peak constraint rows over the rollouts (`mjData.maxuse_efc`).
    pub peak_constraints: usize,
    /// Env steps rolled out for the arena peak (random and scripted).
    pub rollout_steps: u64,
}

fn step_random(env: &mut Env, rng: &mut ChaCha8Rng, steps: usize) -> Result<()> {
    for _ in 0..steps {
        let a: [f32; ACTION_DIM] = std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0));
        if env.step(&a)?.truncated {
            break;
        }
    }
    Ok(())
}

#[derive(Default)]
struct Peak {
    arena: usize,
    con: usize,
    efc: usize,
}

impl Peak {
    fn read(&mut self, env: &Env) {
        self.arena = self.arena.max(env.arena_use().0);
        let (c, e) = env.peak_contacts_constraints();
        self.con = self.con.max(c);
        self.efc = self.efc.max(e);
    }
}

/// Random episodes (gripper and hand actions uniform in [-1, 1]) and scripted episodes (the
/// task's expert policy, when it has one, plus Gaussian noise of 0.3) over goal variations of
/// seed 0, full length; the peak arena use of all of them.
fn rollouts(env: &mut Env, episodes: usize, rng: &mut ChaCha8Rng, peak: &mut Peak) -> Result<u64> {
    let variations = goal_variations(env.name(), 0)?;
    let mut steps = 0;
    for ep in 0..episodes {
        let mut obs = env.reset(&variations[ep % variations.len()])?;
        let scripted = ep % 2 == 1 && policies::policy(env.name()).is_ok();
        for _ in 0..MAX_PATH_LENGTH {
            let mut a: [f32; ACTION_DIM] = if scripted {
                policies::scripted_action(env.name(), &obs)?
            } else {
                std::array::from_fn(|_| rng.gen_range(-1.0f32..1.0))
            };
            if scripted {
                for v in &mut a {
                    *v += rng.gen_range(-0.3f32..0.3);
                }
            }
            let out = env.step(&a)?;
            steps += 1;
            obs = out.obs;
            if out.truncated {
                break;
            }
        }
        peak.read(env);
    }
    Ok(steps)
}

/// Measures `tasks` with `envs_per_task` environments each (see the module docs), rolling out
/// `episodes` full episodes per task for the arena peak.
pub fn memory_probe(tasks: &[&str], envs_per_task: usize, episodes: usize) -> Result<MemoryProbe> {
    let envs_per_task = envs_per_task.max(1);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let rss_base = rss_mb();
    let mut envs: Vec<Vec<Env>> = Vec::new();
    for (t, task) in tasks.iter().enumerate() {
        let mut env = Env::new(task)?;
        env.reset_variation(0, t % 50)?;
        step_random(&mut env, &mut rng, 100)?;
        envs.push(vec![env]);
    }
    let rss_one = rss_mb();
    for group in &mut envs {
        for k in 1..envs_per_task {
            let mut env = Env::new(group[0].name())?;
            env.reset_variation(0, k % 50)?;
            step_random(&mut env, &mut rng, 100)?;
            group.push(env);
        }
    }
    let rss_all = rss_mb();
    let model_shared = envs.iter().all(|g| {
        g.iter()
            .all(|e| std::sync::Arc::ptr_eq(e.model(), g[0].model()))
    });
    let mut peak = Peak::default();
    let mut rollout_steps = 0;
    if episodes > 0 {
        for group in &mut envs {
            rollout_steps += rollouts(&mut group[0], episodes, &mut rng, &mut peak)?;
        }
    }
    let first = &envs[0][0];
    let n = tasks.len() as f64;
    Ok(MemoryProbe {
        tasks: tasks.iter().map(|t| t.to_string()).collect(),
        envs_per_task,
        rss_base_mb: rss_base,
        rss_one_per_task_mb: rss_one,
        rss_all_mb: rss_all,
        mb_per_additional_env: (envs_per_task > 1)
            .then(|| (rss_all - rss_one) / (n * (envs_per_task - 1) as f64)),
        mb_first_env: (rss_one - rss_base) / n,
        model_buffer_bytes: envs.iter().map(|g| g[0].model().buffer_bytes()).sum(),
        model_released_bytes: envs.iter().map(|g| g[0].model().released_bytes()).sum(),
        model_shared,
        arena_bytes: first.arena_use().1,
        arena_peak_bytes: peak.arena,
        peak_contacts: peak.con,
        peak_constraints: peak.efc,
        rollout_steps,
    })
}

/// One task's row of the report.
#[derive(Debug, Clone, Serialize)]
pub struct MemoryRow {
    /// Meta-World v3 task name.
    pub task: String,
    /// RSS of the model plus the first environment's data, MB ([`MemoryProbe::mb_first_env`]).
    pub mb_first_env: f64,
    /// RSS of each further environment, MB (NaN when only one was measured).
    pub mb_per_additional_env: f64,
    /// RSS with one environment, MB.
    pub rss_one_mb: f64,
    /// RSS with `envs_per_task` environments, MB.
    pub rss_n_mb: f64,
    /// Size of the compiled model's buffer (`mjModel.nbuffer`), MB.
    pub model_buffer_mb: f64,
    /// Part of that buffer given back to the OS ([`terl_sim::Model::release_render_data`]), MB.
    pub model_released_mb: f64,
    /// Whether all environments of the task hold one model.
    pub model_shared: bool,
    /// Peak `mjData.maxuse_arena` over the rollouts, bytes.
    pub arena_peak_bytes: usize,
    /// Peak contacts over the rollouts (`mjData.maxuse_con`).
    pub peak_contacts: usize,
    /// Peak constraint rows over the rollouts (`mjData.maxuse_efc`).
    pub peak_constraints: usize,
}

/// The report `terl bench env --memory` prints.
#[derive(Debug, Clone, Serialize)]
pub struct MemoryReport {
    /// Environments per task in the 1-vs-N measurement.
    pub envs_per_task: usize,
    /// Episodes rolled out per task for the arena peak.
    pub episodes_per_task: usize,
    /// One row per task, each from its own single-task probe.
    pub tasks: Vec<MemoryRow>,
    /// Smallest `mb_per_additional_env` over the tasks, MB.
    pub mb_per_additional_env_min: f64,
    /// Median `mb_per_additional_env` over the tasks, MB.
    pub mb_per_additional_env_median: f64,
    /// Largest `mb_per_additional_env` over the tasks, MB.
    pub mb_per_additional_env_max: f64,
    /// The floor each task's `mb_per_additional_env` must stay within, MB.
    pub max_mb_per_additional_env_floor: f64,
    /// Tasks above the per-environment floor.
    pub above_floor: Vec<String>,
    /// The arena every environment gets, bytes.
    pub arena_bytes: usize,
    /// The largest arena peak seen over all tasks, bytes.
    pub arena_peak_bytes_max: usize,
    /// `arena_bytes / arena_peak_bytes_max`.
    pub arena_headroom: f64,
    /// An MT10 actor's set: one environment of each MT10 task in a fresh process.
    pub mt10_set: MemoryProbe,
    /// The floor for the MT10 set's total RSS (`mt10_set.rss_all_mb`), MB.
    pub mt10_set_floor_mb: f64,
    /// Whether every task is within the per-environment floor with a shared model and the MT10
    /// set within its floor.
    pub floors_met: bool,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Assembles the report from one single-task probe per task and the MT10-set probe.
pub fn memory_report(
    per_task: Vec<MemoryProbe>,
    mt10_set: MemoryProbe,
    episodes_per_task: usize,
) -> MemoryReport {
    let rows: Vec<MemoryRow> = per_task
        .iter()
        .map(|p| MemoryRow {
            task: p.tasks.join(","),
            mb_first_env: p.mb_first_env,
            mb_per_additional_env: p.mb_per_additional_env.unwrap_or(f64::NAN),
            rss_one_mb: p.rss_one_per_task_mb,
            rss_n_mb: p.rss_all_mb,
            model_buffer_mb: p.model_buffer_bytes as f64 / 1e6,
            model_released_mb: p.model_released_bytes as f64 / 1e6,
            model_shared: p.model_shared,
            arena_peak_bytes: p.arena_peak_bytes,
            peak_contacts: p.peak_contacts,
            peak_constraints: p.peak_constraints,
        })
        .collect();
    let per: Vec<f64> = rows.iter().map(|r| r.mb_per_additional_env).collect();
    let above_floor: Vec<String> = rows
        .iter()
        .filter(|r| {
            // NaN (no measurement) counts as above the floor.
            let within = r.mb_per_additional_env <= MAX_MB_PER_ADDITIONAL_ENV;
            !within || !r.model_shared
        })
        .map(|r| r.task.clone())
        .collect();
    let arena_bytes = per_task.first().map_or(0, |p| p.arena_bytes);
    let arena_peak_bytes_max = per_task
        .iter()
        .map(|p| p.arena_peak_bytes)
        .max()
        .unwrap_or(0);
    let floors_met = above_floor.is_empty() && mt10_set.rss_all_mb <= MAX_MT10_SET_MB;
    MemoryReport {
        envs_per_task: per_task.first().map_or(0, |p| p.envs_per_task),
        episodes_per_task,
        mb_per_additional_env_min: per.iter().copied().fold(f64::INFINITY, f64::min),
        mb_per_additional_env_median: median(per.clone()),
        mb_per_additional_env_max: per.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        max_mb_per_additional_env_floor: MAX_MB_PER_ADDITIONAL_ENV,
        above_floor,
        arena_bytes,
        arena_peak_bytes_max,
        arena_headroom: arena_bytes as f64 / arena_peak_bytes_max.max(1) as f64,
        tasks: rows,
        mt10_set,
        mt10_set_floor_mb: MAX_MT10_SET_MB,
        floors_met,
    }
}
