//! The single-process training loop: one [`VecEnvironment`] for data (stepped by the shared
//! rollout loop, [`crate::rollout`]), one for evaluation, one [`Sac`] learner, per-task replay.
//! No I/O: progress goes to a callback, which is where a binary logs, writes checkpoints or
//! stops early.

use crate::batch::Batch;
use crate::env::{StepBuffers, VecEnvironment};
use crate::error::SacError;
use crate::policy::Policy;
use crate::replay::MultiTaskReplay;
use crate::rollout::{
    self, EpisodeRecord, Flow, PolicySource, RolloutError, RolloutProgress, StepRecord,
    TransitionSink,
};
use crate::sac::{Sac, UpdateStats};
use crate::success::SuccessWindow;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::time::Instant;

/// Schedule of a training run (the learner's own settings are in [`crate::SacConfig`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Transitions to collect over all environments.
    pub total_env_steps: u64,
    /// Transitions collected with uniform random actions before the policy acts and updates start.
    pub warmup_env_steps: u64,
    /// Gradient updates per step of the whole vector of environments (may be fractional).
    pub updates_per_vec_step: f64,
    /// Ring-buffer size of each task's replay.
    pub replay_capacity_per_task: usize,
    /// Evaluate every this many transitions (0: only at the end).
    pub eval_every_env_steps: u64,
    /// Deterministic evaluation episodes per evaluation environment.
    pub eval_episodes_per_env: usize,
    /// Training success rate is over each task's last this many episodes.
    pub success_window: usize,
    /// Stop as soon as an evaluation's mean success reaches this.
    pub stop_at_eval_success: Option<f64>,
    /// Stop after this many consecutive updates that failed on non-finite losses or gradients.
    pub max_consecutive_failed_updates: u64,
    /// Seed of exploration, replay sampling and environment resets.
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            total_env_steps: 1_000_000,
            warmup_env_steps: 10_000,
            updates_per_vec_step: 1.0,
            replay_capacity_per_task: 1_000_000,
            eval_every_env_steps: 50_000,
            eval_episodes_per_env: 5,
            success_window: 50,
            stop_at_eval_success: None,
            max_consecutive_failed_updates: 100,
            seed: 0,
        }
    }
}

/// Result of a deterministic evaluation.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Mean over tasks of the fraction of episodes with success at any step.
    pub success_rate: f64,
    /// Per task (in task-index order, tasks without an environment left out), the fraction of
    /// its episodes with success at any step.
    pub per_task_success: Vec<f64>,
    /// Mean undiscounted episode return over all evaluation episodes.
    pub mean_return: f64,
    /// Evaluation episodes run: environments × `episodes_per_env`.
    pub episodes: usize,
}

/// Where a run is; passed to the progress callback after every evaluation and at the end.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainProgress {
    /// Environment steps taken so far, over all environments.
    pub env_steps: u64,
    /// SAC updates applied so far.
    pub updates: u64,
    /// Training episodes finished so far.
    pub episodes: u64,
    /// Wall-clock seconds since the run started.
    pub wall_s: f64,
    /// Per task, success fraction over its last `success_window` training episodes.
    pub train_success: Vec<f64>,
    /// Losses of the most recent successful update (`None` before the first).
    pub last_update: Option<UpdateStats>,
    /// The most recent evaluation (`None` before the first).
    pub eval: Option<EvalReport>,
    /// Batches the update rejected for non-finite values ([`Sac::rejected_batches`]).
    pub rejected_batches: u64,
    /// Updates stopped by a non-finite loss or gradient; the run fails after
    /// `max_consecutive_failed_updates` of them in a row.
    pub failed_updates: u64,
    /// Steps where the physics went unstable; they are not stored in replay.
    #[serde(default)]
    pub unstable_transitions: u64,
}

/// Summary of a finished run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    /// Progress at the end of the run (after its final evaluation).
    pub final_progress: TrainProgress,
    /// Highest [`EvalReport::success_rate`] over the run's evaluations.
    pub best_eval_success: f64,
    /// Environment steps when an evaluation first reached `stop_at_eval_success` (`None` if
    /// none did or no target was set).
    pub reached_target_at_env_steps: Option<u64>,
    /// Wall-clock seconds since the start at that evaluation.
    pub reached_target_at_wall_s: Option<f64>,
}

/// Runs the deterministic policy until every environment finished `episodes_per_env` episodes.
pub fn evaluate<E: VecEnvironment>(
    policy: &mut Policy,
    env: &mut E,
    episodes_per_env: usize,
    seed: u64,
) -> Result<EvalReport, SacError> {
    let (n, od, ad, nt) = (
        env.num_envs(),
        env.obs_dim(),
        env.act_dim(),
        env.num_tasks(),
    );
    let task_ids = env.task_ids().to_vec();
    let mut obs = vec![0.0; n * od];
    let mut actions = vec![0.0; n * ad];
    let mut out = StepBuffers::new(n, od);
    env.reset_all(seed, &mut obs)
        .map_err(|e| SacError::Env(Box::new(e)))?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut done, mut succeeded, mut ep_success, mut ep_return) =
        (vec![0; n], vec![0; n], vec![false; n], vec![0.0f64; n]);
    let mut total_return = 0.0;
    while done.iter().any(|&d| d < episodes_per_env) {
        policy.act(&obs, &task_ids, true, &mut rng, &mut actions)?;
        env.step(&actions, &mut out)
            .map_err(|e| SacError::Env(Box::new(e)))?;
        for i in 0..n {
            if done[i] >= episodes_per_env {
                continue;
            }
            ep_success[i] |= out.success[i];
            ep_return[i] += out.reward[i] as f64;
            if out.terminated[i] || out.truncated[i] {
                done[i] += 1;
                succeeded[i] += usize::from(ep_success[i]);
                total_return += ep_return[i];
                ep_success[i] = false;
                ep_return[i] = 0.0;
            }
        }
        obs.copy_from_slice(&out.obs);
    }
    let mut per_task = vec![(0usize, 0usize); nt];
    for i in 0..n {
        per_task[task_ids[i]].0 += succeeded[i];
        per_task[task_ids[i]].1 += episodes_per_env;
    }
    let per_task_success: Vec<f64> = per_task
        .iter()
        .filter(|(_, e)| *e > 0)
        .map(|&(s, e)| s as f64 / e as f64)
        .collect();
    let episodes = n * episodes_per_env;
    Ok(EvalReport {
        success_rate: per_task_success.iter().sum::<f64>() / per_task_success.len().max(1) as f64,
        per_task_success,
        mean_return: total_return / episodes.max(1) as f64,
        episodes,
    })
}

/// `terl train`'s policy source: uniform random actions during warm-up, then the learner's
/// newest policy (shared with [`TrainSink`], which updates it).
struct TrainPolicy<'a, 's> {
    sac: &'a RefCell<&'s mut Sac<f32>>,
    policy: Policy,
    warmup_env_steps: u64,
    total_env_steps: u64,
    acting: bool,
}

impl PolicySource for TrainPolicy<'_, '_> {
    type Error = SacError;

    fn refresh(&mut self, progress: &RolloutProgress) -> Result<Flow, SacError> {
        if progress.env_steps >= self.total_env_steps {
            return Ok(Flow::Stop);
        }
        self.acting = progress.env_steps >= self.warmup_env_steps;
        if self.acting {
            let sac = self.sac.borrow();
            self.policy
                .set_params(&sac.policy_params_f32(), sac.updates())?;
        }
        Ok(Flow::Continue)
    }

    fn version(&self) -> u64 {
        self.policy.version
    }

    fn act(
        &mut self,
        obs: &[f32],
        task_ids: &[usize],
        rng: &mut ChaCha8Rng,
        actions: &mut [f32],
        _guided: &mut [bool],
    ) -> Result<bool, SacError> {
        if !self.acting {
            return Ok(false);
        }
        self.policy.act(obs, task_ids, false, rng, actions)?;
        Ok(true)
    }
}

/// `terl train`'s transition sink: per-task replay, the update-to-data ratio
/// (`updates_per_vec_step` after warm-up), evaluations and the progress callback.
struct TrainSink<'a, 's, V, F> {
    sac: &'a RefCell<&'s mut Sac<f32>>,
    config: &'a TrainConfig,
    replay: MultiTaskReplay,
    batch: Batch,
    windows: Vec<SuccessWindow>,
    progress: TrainProgress,
    report: TrainReport,
    eval_env: &'a mut V,
    eval_policy: Policy,
    update_credit: f64,
    failed_in_a_row: u64,
    next_eval: u64,
    eval_round: u64,
    start: Instant,
    on_progress: F,
}

impl<V, F> TransitionSink for TrainSink<'_, '_, V, F>
where
    V: VecEnvironment,
    F: FnMut(&TrainProgress, &Sac<f32>),
{
    type Error = SacError;

    fn transition(&mut self, t: &StepRecord<'_>) -> Result<(), SacError> {
        self.replay
            .push(t.task, t.obs, t.action, t.reward, t.next_obs, t.terminated);
        Ok(())
    }

    fn episode(&mut self, e: &EpisodeRecord<'_>) -> Result<(), SacError> {
        self.progress.episodes += 1;
        self.windows[e.task].push(e.success);
        Ok(())
    }

    fn end_step(
        &mut self,
        rollout: &RolloutProgress,
        rng: &mut ChaCha8Rng,
    ) -> Result<Flow, SacError> {
        let config = self.config;
        self.progress.env_steps = rollout.env_steps;
        // Not transitions of the task (see `StepBuffers::unstable`): dropped, counted.
        self.progress.unstable_transitions = rollout.unstable_steps;
        let mut sac = self.sac.borrow_mut();
        if rollout.env_steps >= config.warmup_env_steps {
            self.update_credit += config.updates_per_vec_step;
            while self.update_credit >= 1.0 {
                self.update_credit -= 1.0;
                self.replay
                    .sample_into(sac.config().batch_size, rng, &mut self.batch);
                match sac.update(&self.batch) {
                    Ok(stats) => {
                        self.progress.last_update = Some(stats);
                        self.failed_in_a_row = 0;
                    }
                    Err(SacError::NonFiniteBatch { .. }) => {}
                    Err(
                        e @ (SacError::NonFiniteLoss { .. } | SacError::NonFiniteGradient { .. }),
                    ) => {
                        self.progress.failed_updates += 1;
                        self.failed_in_a_row += 1;
                        if self.failed_in_a_row >= config.max_consecutive_failed_updates {
                            return Err(e);
                        }
                    }
                    Err(e) => return Err(e),
                }
            }
        }

        let finished = rollout.env_steps >= config.total_env_steps;
        if rollout.env_steps < self.next_eval && !finished {
            return Ok(Flow::Continue);
        }
        self.next_eval = self.next_eval.saturating_add(config.eval_every_env_steps);
        self.eval_round += 1;
        self.eval_policy
            .set_params(&sac.policy_params_f32(), sac.updates())?;
        let eval_seed = config.seed.wrapping_add(1_000_003 * self.eval_round);
        let eval = evaluate(
            &mut self.eval_policy,
            &mut *self.eval_env,
            config.eval_episodes_per_env,
            eval_seed,
        )?;
        self.report.best_eval_success = self.report.best_eval_success.max(eval.success_rate);
        let reached = config
            .stop_at_eval_success
            .is_some_and(|t| eval.success_rate >= t);
        self.progress.eval = Some(eval);
        fill_progress(&mut self.progress, &self.windows, &sac, self.start);
        (self.on_progress)(&self.progress, &sac);
        if reached {
            self.report.reached_target_at_env_steps = Some(self.progress.env_steps);
            self.report.reached_target_at_wall_s = Some(self.progress.wall_s);
            return Ok(Flow::Stop);
        }
        Ok(Flow::Continue)
    }
}

/// The [`SacError`] behind a rollout error (an environment's error as [`SacError::Env`]).
fn sac_error(e: RolloutError) -> SacError {
    match e {
        RolloutError::Env(e) => SacError::Env(e),
        RolloutError::Policy(e) | RolloutError::Sink(e) => match e.downcast::<SacError>() {
            Ok(e) => *e,
            Err(e) => SacError::Env(e),
        },
    }
}

/// Trains `sac` on `env`, evaluating on `eval_env`, until `total_env_steps` or the success target.
/// The environment loop is [`crate::rollout::run`].
pub fn train<E: VecEnvironment, V: VecEnvironment>(
    sac: &mut Sac<f32>,
    env: &mut E,
    eval_env: &mut V,
    config: &TrainConfig,
    on_progress: impl FnMut(&TrainProgress, &Sac<f32>),
) -> Result<TrainReport, SacError> {
    let (n, od, ad, nt) = (
        env.num_envs(),
        env.obs_dim(),
        env.act_dim(),
        env.num_tasks(),
    );
    let sc = sac.config().clone();
    if (od, ad, nt) != (sc.obs_dim, sc.act_dim, sc.num_tasks) {
        return Err(SacError::Config(format!(
            "environment has obs/act/tasks {od}/{ad}/{nt}, SAC config {}/{}/{}",
            sc.obs_dim, sc.act_dim, sc.num_tasks
        )));
    }
    let start = Instant::now();
    let mut policy = Policy::new(sac.policy_spec(), n);
    let eval_policy = Policy::new(sac.policy_spec(), eval_env.num_envs());
    policy.set_params(&sac.policy_params_f32(), sac.updates())?;
    let sac = RefCell::new(sac);
    let mut source = TrainPolicy {
        sac: &sac,
        policy,
        warmup_env_steps: config.warmup_env_steps,
        total_env_steps: config.total_env_steps,
        acting: false,
    };
    let mut sink = TrainSink {
        sac: &sac,
        config,
        replay: MultiTaskReplay::new(nt, config.replay_capacity_per_task, od, ad),
        batch: Batch::with_capacity(sc.batch_size, od, ad),
        windows: vec![SuccessWindow::new(config.success_window); nt],
        progress: TrainProgress {
            train_success: vec![0.0; nt],
            ..Default::default()
        },
        report: TrainReport::default(),
        eval_env,
        eval_policy,
        update_credit: 0.0,
        failed_in_a_row: 0,
        next_eval: if config.eval_every_env_steps > 0 {
            config.eval_every_env_steps
        } else {
            u64::MAX
        },
        eval_round: 0,
        start,
        on_progress,
    };
    rollout::run(env, &mut source, &mut sink, config.seed).map_err(sac_error)?;
    let TrainSink {
        mut progress,
        mut report,
        windows,
        ..
    } = sink;
    fill_progress(&mut progress, &windows, &sac.borrow(), start);
    report.final_progress = progress;
    Ok(report)
}

fn fill_progress(
    progress: &mut TrainProgress,
    windows: &[SuccessWindow],
    sac: &Sac<f32>,
    start: Instant,
) {
    progress.wall_s = start.elapsed().as_secs_f64();
    progress.updates = sac.updates();
    progress.rejected_batches = sac.rejected_batches();
    for (s, w) in progress.train_success.iter_mut().zip(windows) {
        *s = w.rate();
    }
}
