//! Deterministic evaluation of a policy on Meta-World's goal variations: what `terl eval` and
//! the cluster's in-run evaluator (the selector) both run.
//!
//! # Protocol (Meta-World MT benchmarks)
//!
//! Each task has 50 goal variations ([`terl_sim::metaworld::goal_variations`]`(task, seed)`,
//! the same list the run trained on when `seed` is the run's `variation_seed`). Episode `k` of a
//! task starts from variation `k mod 50` and runs the deterministic policy (`tanh` of the
//! Gaussian mean) for the full 500 steps (Meta-World never ends an episode early; a physics
//! instability cuts it short and is counted). An episode succeeds if the task's success
//! criterion held at *any* step (`info["success"]`, Meta-World's evaluation rule). Per task:
//! success rate, mean undiscounted return, mean first-success step (1-based, over successful
//! episodes only); over tasks: the unweighted mean of the per-task numbers.
//!
//! With the default 50 episodes per task every variation is used once. Because both the policy
//! and the simulation are deterministic, episodes beyond 50 repeat earlier ones exactly.
//!
//! # Tasks the policy was not trained on (MT-Test zero-shot)
//!
//! The policy's input is `obs ⊕ task one-hot`. A task outside the trained list has no one-hot;
//! [`UnseenTaskEncoding`] chooses what it gets instead. The default, [`UnseenTaskEncoding::Uniform`]
//! (`1/num_tasks` in every slot), is chosen on purpose: the first layer is linear in the task
//! vector, so the uniform vector gives exactly the *average* of the trained tasks'
//! task-conditioning (the mean of their first-layer task columns), stays on the simplex the
//! network was trained on (every training input's task part sums to 1), and prefers no trained
//! task. All zeros ([`UnseenTaskEncoding::Zeros`]) drops the task term entirely, an input the
//! network never saw (sum 0); it is offered for comparison. A CARE policy with task-description
//! context conditions such a task on that task's own published description embedding instead
//! ([`UnseenTaskEncoding::TaskEmbedding`], the only setting that applies to it).
//!
//! # Parallelism and determinism
//!
//! Episodes are spread over `threads` worker threads, each with its own environments and its own
//! copy of the policy, stepping up to [`BATCH`] episodes of one task in lockstep (one batched
//! policy call per step). Results are aggregated in episode order, so they do not depend on the
//! thread count.

use std::collections::HashMap;
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use rand::SeedableRng;
use serde::{Deserialize, Serialize};
use terl_rl::{Policy, SacError};
use terl_sim::metaworld::{goal_variations, MAX_PATH_LENGTH, NUM_VARIATIONS};
use terl_sim::{Env, SimError, Step, ACTION_DIM, OBS_DIM};

/// Episodes of one task stepped together in one worker (one policy call per step for all).
pub const BATCH: usize = 10;

/// Why an evaluation could not run.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The checkpoint's policy does not fit the task set or the environment.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// The file is not a policy checkpoint, or no checkpoint was found.
    #[error("checkpoint {path}: {reason}")]
    Checkpoint {
        /// The file or directory given.
        path: String,
        /// What is wrong with it.
        reason: String,
    },
    /// Invalid settings (no tasks, zero episodes, ...).
    #[error("invalid evaluation settings: {0}")]
    Settings(String),
    /// The caller's cancel flag was set.
    #[error("evaluation cancelled")]
    Cancelled,
    /// Building or stepping a Meta-World environment failed.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// A SAC error from the policy, e.g. its tensors are missing from the checkpoint or do not have
    /// the shapes its config states.
    #[error(transparent)]
    Policy(#[from] SacError),
    /// The observer of [`observe_episode`] failed (e.g. the renderer or the video encoder).
    #[error("{0}")]
    Observer(String),
}

/// What a task outside the trained list gets as its task vector (see the module docs).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UnseenTaskEncoding {
    /// `1/num_tasks` in every slot: the average of the trained tasks' conditioning (default).
    #[default]
    Uniform,
    /// All zeros: no task term.
    Zeros,
    /// The task's own published description embedding: CARE with task-description context
    /// (`[sac.care] context = "task_embeddings"`) only, where it is the only setting.
    #[serde(rename = "task-embedding")]
    TaskEmbedding,
}

impl UnseenTaskEncoding {
    /// Its name, as `FromStr` and serde read it: `"uniform"`, `"zeros"` or `"task-embedding"`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Uniform => "uniform",
            Self::Zeros => "zeros",
            Self::TaskEmbedding => "task-embedding",
        }
    }

    /// The setting for a policy: `chosen`, or by default `TaskEmbedding` for CARE with
    /// task-description context and `Uniform` for any other policy.
    ///
    /// # Errors
    /// [`EvalError::Settings`] when `chosen` does not apply to the policy: anything but
    /// `TaskEmbedding` for CARE with task-description context, or `TaskEmbedding` for another
    /// policy.
    pub fn for_policy(chosen: Option<Self>, sac: &terl_rl::SacConfig) -> Result<Self, EvalError> {
        let embeddings = sac
            .care
            .as_ref()
            .is_some_and(|c| c.context == terl_rl::CareContext::TaskEmbeddings);
        match (chosen, embeddings) {
            (None | Some(Self::TaskEmbedding), true) => Ok(Self::TaskEmbedding),
            (Some(other), true) => Err(EvalError::Settings(format!(
                "unseen-task encoding `{}` does not apply to this CARE policy: it conditions a \
                 task it was not trained on on that task's published description embedding \
                 (task-embedding)",
                other.as_str()
            ))),
            (Some(Self::TaskEmbedding), false) => Err(EvalError::Settings(
                "unseen-task encoding `task-embedding` applies only to CARE policies with \
                 context = \"task_embeddings\"; use uniform or zeros"
                    .into(),
            )),
            (chosen, false) => Ok(chosen.unwrap_or_default()),
        }
    }
}

impl FromStr for UnseenTaskEncoding {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "uniform" => Ok(Self::Uniform),
            "zeros" => Ok(Self::Zeros),
            "task-embedding" => Ok(Self::TaskEmbedding),
            other => Err(format!(
                "unknown task encoding `{other}` (uniform, zeros or task-embedding)"
            )),
        }
    }
}

/// The task vector (length `num_tasks` of the policy) one evaluated task is conditioned on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskEncoding {
    /// One-hot of this position in the trained task list (a trained task).
    OneHot(usize),
    /// `1/num_tasks` everywhere (an unseen task, [`UnseenTaskEncoding::Uniform`]).
    Uniform,
    /// All zeros (an unseen task, [`UnseenTaskEncoding::Zeros`]).
    Zeros,
    /// The task's own published description embedding (an unseen task of a CARE policy with
    /// task-description context, [`encoding_row`]); no vector over the one-hot slots (zeros).
    TaskEmbedding,
}

impl TaskEncoding {
    /// Writes the vector into `out` (length `num_tasks`).
    pub fn write(self, out: &mut [f32]) {
        match self {
            Self::OneHot(i) => {
                out.fill(0.0);
                out[i] = 1.0;
            }
            Self::Uniform => out.fill(1.0 / out.len().max(1) as f32),
            Self::Zeros | Self::TaskEmbedding => out.fill(0.0),
        }
    }

    /// `one-hot:<i>`, `uniform`, `zeros` or `task-embedding`.
    pub fn label(self) -> String {
        match self {
            Self::OneHot(i) => format!("one-hot:{i}"),
            Self::Uniform => "uniform".into(),
            Self::Zeros => "zeros".into(),
            Self::TaskEmbedding => "task-embedding".into(),
        }
    }
}

/// The task part of the policy's input for `task`: its [`TaskEncoding`] over the trained
/// tasks, or with CARE ([`terl_rl::care`]) a context row: a trained task's own row of the
/// policy's context table, and for a task it was not trained on under task-description
/// context that task's own published description embedding (CARE's way to a new task; the
/// unseen-task setting then does not apply), else the encoding over the one-hot rows.
pub fn encoding_row(policy: &Policy, task: &EvalTask) -> Vec<f32> {
    let spec = policy.spec();
    let nt = spec.num_tasks;
    if let Some(care) = &spec.care {
        if let TaskEncoding::OneHot(i) = task.encoding {
            if let Some(row) = policy.care_context(i) {
                return row.to_vec();
            }
        }
        if care.context == terl_rl::CareContext::TaskEmbeddings {
            if let Some(e) = terl_rl::care::task_embedding(task.name) {
                return e.iter().map(|v| v.max(0.0)).collect();
            }
        }
    }
    let mut row = vec![0.0f32; nt];
    task.encoding.write(&mut row);
    row
}

/// One task to evaluate and the task vector the policy sees for it.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalTask {
    /// Meta-World task name (e.g. `reach-v3`).
    pub name: &'static str,
    /// The task vector the policy is conditioned on for this task.
    pub encoding: TaskEncoding,
}

/// Pairs every task of `eval_tasks` with its encoding: the one-hot of its position in `trained`
/// (the run's task list, whose length must be the policy's `num_tasks`), or `unseen` for a task
/// the policy was not trained on.
pub fn plan_tasks(
    eval_tasks: &[&'static str],
    trained: &[&str],
    unseen: UnseenTaskEncoding,
) -> Vec<EvalTask> {
    eval_tasks
        .iter()
        .map(|&name| EvalTask {
            name,
            encoding: match trained.iter().position(|t| *t == name) {
                Some(i) => TaskEncoding::OneHot(i),
                None => match unseen {
                    UnseenTaskEncoding::Uniform => TaskEncoding::Uniform,
                    UnseenTaskEncoding::Zeros => TaskEncoding::Zeros,
                    UnseenTaskEncoding::TaskEmbedding => TaskEncoding::TaskEmbedding,
                },
            },
        })
        .collect()
}

/// How much to evaluate and where.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalSettings {
    /// Episodes per task (50 = each goal variation once, the benchmarks' protocol).
    pub episodes_per_task: usize,
    /// Seed of the goal variations (the run's `variation_seed` evaluates on its own 50).
    pub variation_seed: u64,
    /// Worker threads (each with its own environments and policy copy).
    pub threads: usize,
    /// Episodes of one task stepped in lockstep by a worker, i.e. environments kept per task
    /// and worker (1..=[`BATCH`]; default [`BATCH`]). Results do not depend on it; memory does:
    /// the environments of a task share its compiled model (about 9 MB, once per process), and
    /// each adds about 0.4 MB (its `mjData` and task state; `docs/results/env-memory/`), so an
    /// evaluator keeps about `tasks × 9 MB + threads × tasks × batch × 0.4 MB`.
    pub batch: usize,
}

impl Default for EvalSettings {
    fn default() -> Self {
        Self {
            episodes_per_task: NUM_VARIATIONS,
            variation_seed: 0,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            batch: BATCH,
        }
    }
}

/// Per-task result of an evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskEvalStats {
    /// Meta-World task name.
    pub task: String,
    /// `one-hot:<i>` for a trained task, else the unseen-task encoding used.
    pub encoding: String,
    /// Whether the policy was trained on this task (its encoding is a one-hot).
    pub trained: bool,
    /// Episodes evaluated.
    pub episodes: usize,
    /// Episodes with success at any step.
    pub successes: usize,
    /// Fraction of episodes with success at any step, in [0, 1].
    pub success_rate: f64,
    /// Mean undiscounted episode return.
    pub mean_return: f64,
    /// Mean 1-based step of the first success over successful episodes (None: no success).
    pub mean_first_success_step: Option<f64>,
    /// Episodes cut short by a physics instability (counted as episodes).
    pub unstable_episodes: usize,
}

/// Result of one evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalSummary {
    /// Unweighted mean over tasks of the success rate.
    pub mean_success_rate: f64,
    /// Unweighted mean over tasks of the mean return.
    pub mean_return: f64,
    /// Per-task results, in the order the tasks were given.
    pub tasks: Vec<TaskEvalStats>,
    /// Episodes evaluated per task ([`EvalSettings::episodes_per_task`]).
    pub episodes_per_task: usize,
    /// Seed of the goal variations evaluated on.
    pub variation_seed: u64,
    /// Policy version (learner updates) of the evaluated weights.
    pub policy_version: u64,
    /// Environment steps simulated by the evaluation.
    pub eval_env_steps: u64,
    /// Worker threads used: the requested count, at most one per lockstep chunk of episodes.
    pub threads: usize,
    /// Wall-clock duration of the evaluation, in seconds.
    pub wall_seconds: f64,
    /// CPU time of the worker threads (Linux `/proc/thread-self/schedstat`; None elsewhere).
    pub cpu_seconds: Option<f64>,
}

/// What one evaluation episode did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Episode {
    /// Undiscounted episode return (the sum of the f32-rounded rewards, as the evaluation sums).
    pub ret: f64,
    /// 1-based step of the first success (`None`: no success).
    pub first_success: Option<u32>,
    /// Cut short by a physics instability.
    pub unstable: bool,
    /// Steps taken (500 unless unstable).
    pub steps: u32,
}

/// CPU time of the calling thread, seconds.
fn thread_cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: u64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns as f64 * 1e-9)
}

/// Runs the deterministic `policy` on `tasks` (see the module docs for the protocol).
/// `on_episodes(n)` is called (from worker threads) whenever `n` more episodes finished; once
/// `cancel` is set, every worker stops at its next step and the result is
/// [`EvalError::Cancelled`].
///
/// Errors: [`EvalError::Shape`] when the policy does not take Meta-World's 39-value observation
/// and 4-value action or a one-hot index is outside its task count; [`EvalError::Settings`] for
/// no tasks or zero episodes; simulation and policy errors as they happen.
///
/// Builds its environments for this one call; a caller that evaluates repeatedly in one process
/// should keep an [`EvalEnvs`] and call [`evaluate_policy_with`] instead.
pub fn evaluate_policy(
    policy: &Policy,
    tasks: &[EvalTask],
    settings: &EvalSettings,
    on_episodes: &(dyn Fn(usize) + Sync),
    cancel: Option<&AtomicBool>,
) -> Result<EvalSummary, EvalError> {
    evaluate_policy_with(
        &EvalEnvs::default(),
        policy,
        tasks,
        settings,
        on_episodes,
        cancel,
    )
}

/// Environments kept between evaluations: one set per worker thread, each a pool of
/// [`Env`]s per task, reused by every later [`evaluate_policy_with`] call that is given it.
///
/// Building MuJoCo environments anew for every evaluation (up to [`BATCH`] per task and worker)
/// and freeing them afterwards leaves the allocator's heap fragmented, so a process that
/// evaluates periodically (the cluster's in-run evaluator) grows by hundreds of MB per
/// evaluation; with the environments kept, memory stays at one evaluation's footprint.
/// Results do not depend on reuse: every episode starts with a full reset to its goal variation.
#[derive(Debug, Default)]
pub struct EvalEnvs {
    /// Idle worker sets; a worker takes one (or starts an empty one) and puts it back.
    sets: Mutex<Vec<HashMap<&'static str, Vec<Env>>>>,
    /// Environments built over the life of this value.
    built: AtomicUsize,
}

impl EvalEnvs {
    /// Environments built so far (with reuse, at most `threads × tasks × BATCH` in total).
    pub fn built(&self) -> usize {
        self.built.load(Ordering::Relaxed)
    }

    fn take(&self) -> HashMap<&'static str, Vec<Env>> {
        self.sets
            .lock()
            .ok()
            .and_then(|mut s| s.pop())
            .unwrap_or_default()
    }

    fn give_back(&self, set: HashMap<&'static str, Vec<Env>>) {
        if let Ok(mut s) = self.sets.lock() {
            s.push(set);
        }
    }
}

/// [`evaluate_policy`] with environments taken from and returned to `envs` (built only where
/// `envs` has too few for a task), so repeated evaluations do not rebuild them. Same results
/// and errors as [`evaluate_policy`].
#[allow(clippy::too_many_lines)] // the lock-step evaluation of every task's variations in one place
pub fn evaluate_policy_with(
    envs: &EvalEnvs,
    policy: &Policy,
    tasks: &[EvalTask],
    settings: &EvalSettings,
    on_episodes: &(dyn Fn(usize) + Sync),
    cancel: Option<&AtomicBool>,
) -> Result<EvalSummary, EvalError> {
    let spec = policy.spec();
    if spec.obs_dim != OBS_DIM || spec.act_dim != ACTION_DIM {
        return Err(EvalError::Shape(format!(
            "the policy takes {} observation and {} action values; Meta-World has {OBS_DIM} and {ACTION_DIM}",
            spec.obs_dim, spec.act_dim
        )));
    }
    if let Some(t) = tasks.iter().find(|t| match t.encoding {
        TaskEncoding::OneHot(i) => i >= spec.num_tasks,
        _ => false,
    }) {
        return Err(EvalError::Shape(format!(
            "task {} is encoded as {}, but the policy was trained on {} task(s)",
            t.name,
            t.encoding.label(),
            spec.num_tasks
        )));
    }
    if tasks.is_empty() || settings.episodes_per_task == 0 {
        return Err(EvalError::Settings(
            "at least one task and one episode per task are needed".into(),
        ));
    }
    if settings.episodes_per_task > MAX_EPISODES_PER_TASK {
        return Err(EvalError::Settings(format!(
            "{} episodes per task is more than the {MAX_EPISODES_PER_TASK} allowed (there are \
             {NUM_VARIATIONS} goal variations; the policy and the simulation are deterministic, \
             so more episodes only repeat them)",
            settings.episodes_per_task
        )));
    }
    if !(1..=BATCH).contains(&settings.batch) {
        return Err(EvalError::Settings(format!(
            "a lockstep batch of {} episodes per task is outside 1..={BATCH}",
            settings.batch
        )));
    }
    let batch = settings.batch;
    let start = Instant::now();
    let variations: Vec<Vec<Vec<f64>>> = tasks
        .iter()
        .map(|t| goal_variations(t.name, settings.variation_seed))
        .collect::<Result<_, _>>()?;
    // Jobs: chunks of up to `batch` consecutive episodes of one task.
    let n = settings.episodes_per_task;
    let chunks: Vec<(usize, std::ops::Range<usize>)> = (0..tasks.len())
        .flat_map(|t| {
            (0..n)
                .step_by(batch)
                .map(move |k| (t, k..(k + batch).min(n)))
        })
        .collect();
    let threads = settings.threads.clamp(1, chunks.len());
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Vec<Episode>>> = Mutex::new(vec![vec![]; tasks.len()]);
    let cpu = Mutex::new(Some(0.0f64));
    let first_error: Mutex<Option<EvalError>> = Mutex::new(None);

    let worker = || {
        let cpu_start = thread_cpu_seconds();
        let mut pol = policy.with_max_batch(batch);
        let mut set = envs.take();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        loop {
            if first_error.lock().map(|e| e.is_some()).unwrap_or(true) {
                break;
            }
            let c = next.fetch_add(1, Ordering::Relaxed);
            let Some((t, range)) = chunks.get(c).cloned() else {
                break;
            };
            let task = &tasks[t];
            let pool = set.entry(task.name).or_default();
            let had = pool.len();
            let mut got = Ok(());
            while pool.len() < range.len() {
                match Env::new(task.name) {
                    Ok(env) => pool.push(env),
                    Err(e) => {
                        got = Err(EvalError::from(e));
                        break;
                    }
                }
            }
            envs.built.fetch_add(pool.len() - had, Ordering::Relaxed);
            let got = got.and_then(|()| {
                run_chunk(
                    &mut pol,
                    &mut pool[..range.len()],
                    task,
                    &variations[t],
                    range.clone(),
                    &mut rng,
                    cancel,
                    &mut |_, _, _| Ok(()),
                )
            });
            match got {
                Ok(eps) => {
                    on_episodes(eps.len());
                    if let Ok(mut r) = results.lock() {
                        let slot = &mut r[t];
                        if slot.len() < n {
                            slot.resize(n, Episode::default());
                        }
                        slot[range].copy_from_slice(&eps);
                    }
                }
                Err(e) => {
                    if let Ok(mut f) = first_error.lock() {
                        f.get_or_insert(e);
                    }
                    break;
                }
            }
        }
        envs.give_back(set);
        if let Ok(mut c) = cpu.lock() {
            *c = match (*c, cpu_start, thread_cpu_seconds()) {
                (Some(sum), Some(a), Some(b)) => Some(sum + (b - a)),
                _ => None,
            };
        }
    };
    std::thread::scope(|s| {
        for _ in 1..threads {
            s.spawn(worker);
        }
        worker();
    });
    if let Some(e) = first_error.into_inner().ok().flatten() {
        return Err(e);
    }
    let results = results.into_inner().unwrap_or_default();
    let mut stats = Vec::with_capacity(tasks.len());
    let mut env_steps = 0u64;
    for (task, eps) in tasks.iter().zip(&results) {
        let successes = eps.iter().filter(|e| e.first_success.is_some()).count();
        let firsts: Vec<f64> = eps
            .iter()
            .filter_map(|e| e.first_success.map(f64::from))
            .collect();
        env_steps += eps.iter().map(|e| u64::from(e.steps)).sum::<u64>();
        stats.push(TaskEvalStats {
            task: task.name.to_string(),
            encoding: task.encoding.label(),
            trained: matches!(task.encoding, TaskEncoding::OneHot(_)),
            episodes: eps.len(),
            successes,
            success_rate: successes as f64 / eps.len().max(1) as f64,
            mean_return: eps.iter().map(|e| e.ret).sum::<f64>() / eps.len().max(1) as f64,
            mean_first_success_step: (!firsts.is_empty())
                .then(|| firsts.iter().sum::<f64>() / firsts.len() as f64),
            unstable_episodes: eps.iter().filter(|e| e.unstable).count(),
        });
    }
    let k = stats.len() as f64;
    Ok(EvalSummary {
        mean_success_rate: stats.iter().map(|s| s.success_rate).sum::<f64>() / k,
        mean_return: stats.iter().map(|s| s.mean_return).sum::<f64>() / k,
        tasks: stats,
        episodes_per_task: n,
        variation_seed: settings.variation_seed,
        policy_version: policy.version,
        eval_env_steps: env_steps,
        threads,
        wall_seconds: start.elapsed().as_secs_f64(),
        cpu_seconds: cpu.into_inner().ok().flatten(),
    })
}

/// Calls of an episode observer: `(environment index in the chunk, the environment, the step
/// just taken or `None` right after the reset)`.
type Observer<'a> = dyn FnMut(usize, &Env, Option<&Step>) -> Result<(), EvalError> + 'a;

/// What [`observe_episode`] calls: the environment right after the reset (`None`) and after
/// every step (`Some(step)`).
pub type EpisodeObserver<'a> = dyn FnMut(&Env, Option<&Step>) -> Result<(), EvalError> + 'a;

/// One evaluation episode observed step by step: the episode [`evaluate_policy`] scores as
/// episode `k` of `task` (variation `variations[k mod len]`, the deterministic policy, the same
/// code), stepped in `env` (e.g. one of [`Env::for_rendering`]). `observe` sees the environment
/// right after the reset (`None`) and after every step (`Some(step)`); its error ends the
/// episode.
///
/// # Errors
/// [`EvalError::Shape`] for a policy that does not fit, [`EvalError::Sim`] from the
/// environment, the observer's own error.
pub fn observe_episode(
    policy: &Policy,
    env: &mut Env,
    task: &EvalTask,
    variations: &[Vec<f64>],
    k: usize,
    observe: &mut EpisodeObserver<'_>,
) -> Result<Episode, EvalError> {
    let spec = policy.spec();
    if spec.obs_dim != OBS_DIM || spec.act_dim != ACTION_DIM {
        return Err(EvalError::Shape(format!(
            "the policy takes {} observation and {} action values; Meta-World has {OBS_DIM} and {ACTION_DIM}",
            spec.obs_dim, spec.act_dim
        )));
    }
    if let TaskEncoding::OneHot(i) = task.encoding {
        if i >= spec.num_tasks {
            return Err(EvalError::Shape(format!(
                "task {} is encoded as {}, but the policy was trained on {} task(s)",
                task.name,
                task.encoding.label(),
                spec.num_tasks
            )));
        }
    }
    if variations.is_empty() {
        return Err(EvalError::Settings("no goal variations".into()));
    }
    let mut pol = policy.with_max_batch(1);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let eps = run_chunk(
        &mut pol,
        std::slice::from_mut(env),
        task,
        variations,
        k..k + 1,
        &mut rng,
        None,
        &mut |_, env, step| observe(env, step),
    )?;
    Ok(eps[0])
}

/// Episodes `range` of one task, stepped in lockstep in `pool[..range.len()]` (episode `k` on
/// variation `k mod 50`).
#[allow(clippy::too_many_arguments)]
fn run_chunk(
    policy: &mut Policy,
    pool: &mut [Env],
    task: &EvalTask,
    variations: &[Vec<f64>],
    range: std::ops::Range<usize>,
    rng: &mut rand_chacha::ChaCha8Rng,
    cancel: Option<&AtomicBool>,
    observe: &mut Observer<'_>,
) -> Result<Vec<Episode>, EvalError> {
    let m = range.len();
    let enc_row = encoding_row(policy, task);
    let nt = enc_row.len();
    let mut obs = vec![0.0f32; m * OBS_DIM];
    for (j, k) in range.enumerate() {
        let o = pool[j].reset(&variations[k % variations.len()])?;
        observe(j, &pool[j], None)?;
        for (d, s) in obs[j * OBS_DIM..(j + 1) * OBS_DIM].iter_mut().zip(o) {
            *d = s as f32;
        }
    }
    let mut eps = vec![Episode::default(); m];
    let mut active: Vec<usize> = (0..m).collect();
    let mut rows_obs = Vec::with_capacity(m * OBS_DIM);
    let mut rows_enc = Vec::with_capacity(m * nt);
    let mut actions = vec![0.0f32; m * ACTION_DIM];
    for _ in 0..MAX_PATH_LENGTH {
        if active.is_empty() {
            break;
        }
        if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
            return Err(EvalError::Cancelled);
        }
        rows_obs.clear();
        rows_enc.clear();
        for &j in &active {
            rows_obs.extend_from_slice(&obs[j * OBS_DIM..(j + 1) * OBS_DIM]);
            rows_enc.extend_from_slice(&enc_row);
        }
        let acts = &mut actions[..active.len() * ACTION_DIM];
        policy.act_encoded(&rows_obs, &rows_enc, true, rng, acts)?;
        let mut still = Vec::with_capacity(active.len());
        for (r, &j) in active.iter().enumerate() {
            let step = pool[j].step(&acts[r * ACTION_DIM..(r + 1) * ACTION_DIM])?;
            observe(j, &pool[j], Some(&step))?;
            let e = &mut eps[j];
            e.steps += 1;
            e.ret += f64::from(step.reward as f32);
            if step.success && e.first_success.is_none() {
                e.first_success = Some(e.steps);
            }
            if step.truncated {
                e.unstable = step.unstable;
            } else {
                for (d, s) in obs[j * OBS_DIM..(j + 1) * OBS_DIM].iter_mut().zip(step.obs) {
                    *d = s as f32;
                }
                still.push(j);
            }
        }
        active = still;
    }
    Ok(eps)
}

/// A policy read from a checkpoint of `terl train` or of a cluster learner (both write
/// [`terl_rl::Sac::save_checkpoint`] safetensors: `policy.{layer}.weight|bias` as `f32`, the
/// SAC config as TOML in the `terl.sac_config` metadata, the update count in `counters`).
#[derive(Debug, Clone)]
pub struct PolicyCheckpoint {
    /// The checkpoint file read (after [`resolve_checkpoint`] picked it from a run directory).
    pub path: std::path::PathBuf,
    /// The policy, version = the learner's update count at the checkpoint.
    pub policy: Policy,
    /// The SAC config stored in the checkpoint's `terl.sac_config` metadata.
    pub sac: terl_rl::SacConfig,
    /// The run's `config.toml` (`<run>/config.toml` next to `<run>/checkpoints/`), if found.
    pub run_config: Option<(std::path::PathBuf, crate::RunConfig)>,
    /// The task list a cluster learner's checkpoint records itself (`tasks` of its
    /// `terl.learner_state` metadata), in one-hot order; `None` for other checkpoints.
    pub stored_tasks: Option<Vec<String>>,
}

impl PolicyCheckpoint {
    /// Task names the policy was trained on, in one-hot order, from the run's config.
    pub fn trained_tasks(&self) -> Option<Result<Vec<&'static str>, EvalError>> {
        if let Some(stored) = &self.stored_tasks {
            // The run folder's config.toml must not contradict what the checkpoint records.
            if let Some((path, cfg)) = &self.run_config {
                let listed = crate::resolve_tasks(&cfg.tasks).ok();
                if listed.is_some_and(|l| l.iter().copied().ne(stored.iter().map(String::as_str))) {
                    return Some(Err(EvalError::Shape(format!(
                        "{} records the task list [{}], but its run's {} says tasks = \"{}\": \
                         the run file was changed after training",
                        self.path.display(),
                        stored.join(", "),
                        path.display(),
                        cfg.tasks
                    ))));
                }
            }
            return Some(crate::resolve_tasks(&stored.join(",")).map_err(|e| {
                EvalError::Checkpoint {
                    path: self.path.display().to_string(),
                    reason: format!("its recorded task list: {e:#}"),
                }
            }));
        }
        self.run_config.as_ref().map(|(path, cfg)| {
            crate::resolve_tasks(&cfg.tasks).map_err(|e| EvalError::Checkpoint {
                path: path.display().to_string(),
                reason: format!("{e:#}"),
            })
        })
    }

    /// Checks that `trained` (the run's task list) fits the policy: one one-hot slot per task,
    /// and, for a checkpoint that records its task list, the same tasks in the same order.
    pub fn check_trained_tasks(&self, trained: &[&str]) -> Result<(), EvalError> {
        let nt = self.policy.spec().num_tasks;
        if trained.len() != nt {
            let input = match &self.sac.care {
                None => format!(
                    "input {} = {} observation + {nt} task values",
                    self.sac.policy_input(),
                    self.sac.obs_dim
                ),
                Some(_) => format!("CARE, a task context row for each of {nt}"),
            };
            return Err(EvalError::Shape(format!(
                "{} has a policy for {nt} task(s) ({input}), but its task list [{}] has {}",
                self.path.display(),
                trained.join(", "),
                trained.len()
            )));
        }
        if let Some(stored) = &self.stored_tasks {
            if stored
                .iter()
                .map(String::as_str)
                .ne(trained.iter().copied())
            {
                return Err(EvalError::Shape(format!(
                    "{} was trained on [{}] in this order (recorded in the checkpoint), not [{}]",
                    self.path.display(),
                    stored.join(", "),
                    trained.join(", ")
                )));
            }
        }
        Ok(())
    }
}

/// The checkpoint a path names: a `.safetensors` file as is; a run directory (or its
/// `checkpoints/` directory): its newest SAC checkpoint by name, `final.safetensors` first, then
/// `latest.safetensors` (the single-process trainer's), then the highest `update-<N>`, file times
/// breaking ties only among other names (a copy that does not keep file times resolves the
/// same; the planner's `planner.safetensors` and temporaries are skipped).
pub fn resolve_checkpoint(path: &std::path::Path) -> Result<std::path::PathBuf, EvalError> {
    let err = |reason: String| EvalError::Checkpoint {
        path: path.display().to_string(),
        reason,
    };
    let meta = std::fs::metadata(path).map_err(|e| err(e.to_string()))?;
    if meta.is_file() {
        return Ok(path.to_path_buf());
    }
    if !meta.is_dir() {
        return Err(err(
            "neither a checkpoint file nor a run folder (a device, socket or pipe)".into(),
        ));
    }
    let dir = if path.join("checkpoints").is_dir() {
        path.join("checkpoints")
    } else {
        path.to_path_buf()
    };
    let newest = std::fs::read_dir(&dir)
        .map_err(|e| err(e.to_string()))?
        .filter_map(|e| e.ok())
        .filter(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            // Regular files only (a symbolic link is followed): a pipe or device under a
            // checkpoint's name would block or never end.
            name.ends_with(".safetensors")
                && !name.starts_with("planner")
                && std::fs::metadata(e.path()).is_ok_and(|m| m.is_file())
        })
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            let stem = name.trim_end_matches(".safetensors");
            let rank = match stem {
                "final" => (3, 0),
                "latest" => (2, 0),
                _ => match stem.strip_prefix("update-").map(str::parse::<u64>) {
                    Some(Ok(n)) => (1, n),
                    _ => (0, 0),
                },
            };
            Some((rank, e.metadata().ok()?.modified().ok()?, e.path()))
        })
        .max();
    newest.map(|(_, _, p)| p).ok_or_else(|| {
        err(format!(
            "no checkpoint (*.safetensors) in {}",
            dir.display()
        ))
    })
}

/// Most episodes per task [`evaluate_policy`] accepts.
pub const MAX_EPISODES_PER_TASK: usize = 100_000;

/// Checkpoint metadata key of the trained task list in one-hot order, a JSON array of task
/// names (written by `terl train`; a cluster learner records it in its `terl.learner_state`).
pub const TASKS_KEY: &str = "terl.tasks";

/// Reads the policy of a checkpoint file or run directory ([`resolve_checkpoint`]) and, when it
/// sits in a run folder, that run's `config.toml`.
///
/// Errors: [`EvalError::Checkpoint`] for a missing or unreadable file, one without
/// `terl.sac_config` (e.g. a planner checkpoint) or a bad run config; [`EvalError::Policy`] when
/// the policy tensors are missing or do not have the shapes the config states.
pub fn load_policy_checkpoint(path: &std::path::Path) -> Result<PolicyCheckpoint, EvalError> {
    let path = resolve_checkpoint(path)?;
    let err = |reason: String| EvalError::Checkpoint {
        path: path.display().to_string(),
        reason,
    };
    let file = terl_nn::TensorFile::load(&path).map_err(|e| err(e.to_string()))?;
    let toml = file.metadata.get("terl.sac_config").ok_or_else(|| {
        err(
            "no terl.sac_config metadata: not a policy checkpoint of terl train or a learner"
                .into(),
        )
    })?;
    let sac = terl_rl::SacConfig::from_toml(toml).map_err(|e| err(e.to_string()))?;
    // The config in the metadata sizes the network that is built before the tensors are read:
    // bound it by the bytes the file actually holds (4 per f32 parameter).
    let file_bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
    let params = terl_rl::PolicySpec::from_config(&sac).checked_num_params();
    if params.is_none_or(|p| (p as u64).saturating_mul(4) > file_bytes) {
        return Err(err(format!(
            "its terl.sac_config describes a policy ({} inputs, hidden {:?}) of {} parameters, \
             more than the file's {file_bytes} bytes can hold",
            sac.policy_input(),
            sac.policy_hidden,
            params.map_or("too many".to_string(), |p| p.to_string())
        )));
    }
    let updates = file
        .i64_values("counters", &[2])
        .map(|c| c[0].max(0) as u64)
        .unwrap_or(0);
    let mut policy = Policy::new(terl_rl::PolicySpec::from_config(&sac), 1);
    policy.load(&file, updates)?;
    let run_config = path
        .parent()
        .and_then(|d| {
            [d.join("config.toml"), d.parent()?.join("config.toml")]
                .into_iter()
                .find(|p| p.is_file())
        })
        .map(|p| match crate::RunConfig::load(&p) {
            Ok(cfg) => Ok((p, cfg)),
            Err(e) => Err(EvalError::Checkpoint {
                path: p.display().to_string(),
                reason: format!("{e:#}"),
            }),
        })
        .transpose()?;
    // The task order: a cluster learner records it in its state, `terl train` under TASKS_KEY.
    let string_list = |v: &serde_json::Value| {
        v.as_array()?
            .iter()
            .map(|t| t.as_str().map(str::to_string))
            .collect::<Option<Vec<String>>>()
    };
    let stored_tasks = file
        .metadata
        .get("terl.learner_state")
        .and_then(|s| serde_json::from_str::<serde_json::Value>(s).ok())
        .and_then(|v| string_list(v.get("tasks")?))
        .or_else(|| {
            let v = serde_json::from_str(file.metadata.get(TASKS_KEY)?).ok()?;
            string_list(&v)
        })
        .filter(|t| !t.is_empty());
    Ok(PolicyCheckpoint {
        path,
        policy,
        sac,
        run_config,
        stored_tasks,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_rl::PolicySpec;

    #[test]
    fn a_run_folder_resolves_to_its_newest_checkpoint_by_name_not_file_time() {
        let dir = tempfile::tempdir().unwrap();
        let ck = dir.path().join("checkpoints");
        std::fs::create_dir(&ck).unwrap();
        let touch = |name: &str, age_s: u64| {
            let p = ck.join(name);
            std::fs::write(&p, b"").unwrap();
            let t = std::time::SystemTime::now() - std::time::Duration::from_secs(age_s);
            std::fs::File::options()
                .write(true)
                .open(&p)
                .unwrap()
                .set_modified(t)
                .unwrap();
        };
        // A copy that did not keep file times: the older update is the newest file.
        touch("update-0000000010.safetensors", 100);
        touch("update-0000000002.safetensors", 1);
        touch("planner.safetensors", 0);
        let got = resolve_checkpoint(dir.path()).unwrap();
        assert!(got.ends_with("update-0000000010.safetensors"), "{got:?}");
        touch("final.safetensors", 500);
        let got = resolve_checkpoint(dir.path()).unwrap();
        assert!(got.ends_with("final.safetensors"), "{got:?}");
        // A pipe under the best checkpoint name is passed over, not opened (it would block).
        let fifo = ck.join("latest.safetensors");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        std::fs::remove_file(ck.join("final.safetensors")).unwrap();
        let got = resolve_checkpoint(dir.path()).unwrap();
        assert!(got.ends_with("update-0000000010.safetensors"), "{got:?}");
        // A device is named as what it is, a missing path as missing.
        let e = resolve_checkpoint(std::path::Path::new("/dev/null")).unwrap_err();
        assert!(e.to_string().contains("neither a checkpoint file"), "{e}");
        let e = resolve_checkpoint(&dir.path().join("nope")).unwrap_err();
        assert!(e.to_string().contains("No such file"), "{e}");
    }

    fn policy(num_tasks: usize) -> Policy {
        Policy::new(
            PolicySpec {
                obs_dim: OBS_DIM,
                act_dim: ACTION_DIM,
                num_tasks,
                hidden: vec![16],
                care: None,
            },
            1,
        )
    }

    #[test]
    fn trained_tasks_get_their_one_hot_and_unseen_tasks_the_chosen_vector() {
        let trained = ["reach-v3", "push-v3"];
        let plan = plan_tasks(
            &["push-v3", "door-close-v3"],
            &trained,
            UnseenTaskEncoding::Uniform,
        );
        assert_eq!(plan[0].encoding, TaskEncoding::OneHot(1));
        assert_eq!(plan[1].encoding, TaskEncoding::Uniform);
        let mut v = [9.0f32; 4];
        TaskEncoding::Uniform.write(&mut v);
        assert_eq!(v, [0.25; 4]);
        TaskEncoding::OneHot(2).write(&mut v);
        assert_eq!(v, [0.0, 0.0, 1.0, 0.0]);
        TaskEncoding::Zeros.write(&mut v);
        assert_eq!(v, [0.0; 4]);
        let plan = plan_tasks(&["door-close-v3"], &trained, UnseenTaskEncoding::Zeros);
        assert_eq!(plan[0].encoding, TaskEncoding::Zeros);
        assert_eq!("zeros".parse(), Ok(UnseenTaskEncoding::Zeros));
        assert!("nearest".parse::<UnseenTaskEncoding>().is_err());
    }

    /// A CARE policy with task-description context meets an unseen task through that task's
    /// embedding, so that is its only setting (and the label its evaluations carry); any other
    /// policy takes uniform or zeros, uniform by default.
    #[test]
    fn the_unseen_task_setting_is_resolved_for_the_policy() {
        use UnseenTaskEncoding::{TaskEmbedding, Uniform, Zeros};
        let mtsac = terl_rl::SacConfig::default();
        let care = |context| terl_rl::SacConfig {
            care: Some(terl_rl::CareConfig {
                context,
                ..terl_rl::CareConfig::default()
            }),
            ..terl_rl::SacConfig::default()
        };
        let embeddings = care(terl_rl::CareContext::TaskEmbeddings);
        let one_hot = care(terl_rl::CareContext::OneHot);
        let f = UnseenTaskEncoding::for_policy;
        assert_eq!(f(None, &mtsac).unwrap(), Uniform);
        assert_eq!(f(Some(Zeros), &mtsac).unwrap(), Zeros);
        assert!(f(Some(TaskEmbedding), &mtsac).is_err());
        assert_eq!(f(None, &embeddings).unwrap(), TaskEmbedding);
        assert_eq!(f(Some(TaskEmbedding), &embeddings).unwrap(), TaskEmbedding);
        assert!(f(Some(Uniform), &embeddings).is_err());
        assert_eq!(f(None, &one_hot).unwrap(), Uniform);
        assert!(f(Some(TaskEmbedding), &one_hot).is_err());
        assert_eq!("task-embedding".parse(), Ok(TaskEmbedding));
        let plan = plan_tasks(&["door-close-v3"], &["reach-v3"], TaskEmbedding);
        assert_eq!(plan[0].encoding.label(), "task-embedding");
    }

    #[test]
    fn eval_results_do_not_depend_on_the_thread_count() {
        let tasks = plan_tasks(
            &["reach-v3", "push-v3"],
            &["reach-v3", "push-v3"],
            UnseenTaskEncoding::Uniform,
        );
        let run = |threads| {
            let s = EvalSettings {
                episodes_per_task: 12,
                variation_seed: 3,
                threads,
                batch: BATCH,
            };
            let done = AtomicUsize::new(0);
            let r = evaluate_policy(
                &policy(2),
                &tasks,
                &s,
                &|n| {
                    done.fetch_add(n, Ordering::Relaxed);
                },
                None,
            )
            .unwrap();
            assert_eq!(done.into_inner(), 24);
            r
        };
        let (one, three) = (run(1), run(3));
        assert_eq!(one.tasks, three.tasks);
        assert_eq!(one.mean_return, three.mean_return);
        assert_eq!(one.eval_env_steps, 2 * 12 * 500);
        assert_eq!(three.threads, 3);
    }

    #[test]
    fn a_policy_that_does_not_fit_is_a_shape_error_and_cancel_stops() {
        let task = |encoding| {
            vec![EvalTask {
                name: "reach-v3",
                encoding,
            }]
        };
        let s = EvalSettings {
            episodes_per_task: 1,
            variation_seed: 0,
            threads: 1,
            batch: BATCH,
        };
        let err = evaluate_policy(
            &policy(2),
            &task(TaskEncoding::OneHot(2)),
            &s,
            &|_| {},
            None,
        )
        .unwrap_err();
        assert!(matches!(err, EvalError::Shape(_)), "{err}");
        let wrong_obs = Policy::new(
            PolicySpec {
                obs_dim: 12,
                act_dim: ACTION_DIM,
                num_tasks: 1,
                hidden: vec![4],
                care: None,
            },
            1,
        );
        let err = evaluate_policy(
            &wrong_obs,
            &task(TaskEncoding::OneHot(0)),
            &s,
            &|_| {},
            None,
        )
        .unwrap_err();
        assert!(err.to_string().contains("39"), "{err}");
        let stop = AtomicBool::new(true);
        let err = evaluate_policy(
            &policy(1),
            &task(TaskEncoding::OneHot(0)),
            &s,
            &|_| {},
            Some(&stop),
        )
        .unwrap_err();
        assert!(matches!(err, EvalError::Cancelled));
    }

    #[test]
    fn sizes_from_a_checkpoint_or_the_command_line_are_bounded() {
        // A config in the metadata that describes a network far larger than the file: an
        // error before anything that size is allocated.
        let dir = std::env::temp_dir().join(format!("terl-eval-bound-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("huge.safetensors");
        let mut meta = std::collections::BTreeMap::new();
        meta.insert(
            "terl.sac_config".to_string(),
            "num_tasks = 2\npolicy_hidden = [4096, 4096]\n".to_string(),
        );
        let t = terl_nn::Tensor::from_values("counters", vec![2], &[0.0f32, 0.0]);
        terl_nn::tensors::save_file(&path, &[t], &meta).unwrap();
        let e = load_policy_checkpoint(&path).unwrap_err().to_string();
        assert!(e.contains("more than the file"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
        // Episodes per task above the bound are refused up front.
        let settings = EvalSettings {
            episodes_per_task: MAX_EPISODES_PER_TASK + 1,
            ..EvalSettings::default()
        };
        let plan = plan_tasks(&["reach-v3"], &["reach-v3"], UnseenTaskEncoding::Uniform);
        let e = evaluate_policy(&policy(1), &plan, &settings, &|_| {}, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("allowed"), "{e}");
    }

    /// Resident set size of this process in bytes (Linux `/proc/self/statm`).
    fn rss_bytes() -> u64 {
        let statm = std::fs::read_to_string("/proc/self/statm").unwrap();
        let pages: u64 = statm.split_whitespace().nth(1).unwrap().parse().unwrap();
        pages * 4096
    }

    fn four_tasks() -> Vec<EvalTask> {
        let names = ["reach-v3", "push-v3", "pick-place-v3", "door-open-v3"];
        plan_tasks(&names, &names, UnseenTaskEncoding::Uniform)
    }

    #[test]
    fn kept_environments_are_built_once_and_give_the_same_results() {
        let tasks = four_tasks();
        let s = EvalSettings {
            episodes_per_task: 10,
            variation_seed: 5,
            threads: 1,
            batch: BATCH,
        };
        let p = policy(tasks.len());
        let fresh = evaluate_policy(&p, &tasks, &s, &|_| {}, None).unwrap();
        let envs = EvalEnvs::default();
        let first = evaluate_policy_with(&envs, &p, &tasks, &s, &|_| {}, None).unwrap();
        assert_eq!(envs.built(), tasks.len() * BATCH);
        let second = evaluate_policy_with(&envs, &p, &tasks, &s, &|_| {}, None).unwrap();
        assert_eq!(envs.built(), tasks.len() * BATCH, "environments rebuilt");
        for r in [&first, &second] {
            assert_eq!(r.tasks, fresh.tasks);
            assert_eq!(r.mean_return, fresh.mean_return);
            assert_eq!(r.eval_env_steps, fresh.eval_env_steps);
        }
    }

    #[test]
    fn a_smaller_lockstep_batch_keeps_fewer_environments_and_gives_the_same_results() {
        let tasks = four_tasks();
        let p = policy(tasks.len());
        let settings = |batch| EvalSettings {
            episodes_per_task: 10,
            variation_seed: 5,
            threads: 1,
            batch,
        };
        let full = evaluate_policy(&p, &tasks, &settings(BATCH), &|_| {}, None).unwrap();
        for batch in [1, 3] {
            let envs = EvalEnvs::default();
            let r =
                evaluate_policy_with(&envs, &p, &tasks, &settings(batch), &|_| {}, None).unwrap();
            assert_eq!(envs.built(), tasks.len() * batch);
            assert_eq!(r.tasks, full.tasks, "batch {batch}");
            assert_eq!(r.mean_return, full.mean_return);
        }
        for bad in [0, BATCH + 1] {
            let e = evaluate_policy(&p, &tasks, &settings(bad), &|_| {}, None).unwrap_err();
            assert!(matches!(e, EvalError::Settings(_)), "{e}");
        }
    }

    #[test]
    fn repeated_evaluations_stay_near_the_first_evaluations_footprint() {
        // The in-run evaluator evaluates every few minutes for days: memory after many
        // evaluations must stay near what the first one needed, not grow with each.
        let tasks = four_tasks();
        let s = EvalSettings {
            episodes_per_task: 10,
            variation_seed: 0,
            threads: 1,
            batch: BATCH,
        };
        let p = policy(tasks.len());
        let envs = EvalEnvs::default();
        let before = rss_bytes();
        evaluate_policy_with(&envs, &p, &tasks, &s, &|_| {}, None).unwrap();
        let after_first = rss_bytes();
        let footprint = after_first.saturating_sub(before).max(1);
        for _ in 0..4 {
            evaluate_policy_with(&envs, &p, &tasks, &s, &|_| {}, None).unwrap();
        }
        let growth = rss_bytes().saturating_sub(after_first);
        eprintln!("first evaluation: {footprint} bytes; 4 more: +{growth} bytes");
        assert!(
            growth <= footprint / 2,
            "4 more evaluations grew the resident set by {growth} bytes; the first \
             evaluation's footprint was {footprint} bytes"
        );
    }
}
