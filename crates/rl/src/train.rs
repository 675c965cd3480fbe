//! The single-process training loop: one [`VecEnvironment`] for data, one for evaluation, one
//! [`Sac`] learner, per-task replay. No I/O: progress goes to a callback, which is where a
//! binary logs, writes checkpoints or stops early.

use crate::batch::Batch;
use crate::env::{StepBuffers, VecEnvironment};
use crate::error::SacError;
use crate::policy::Policy;
use crate::replay::MultiTaskReplay;
use crate::sac::{Sac, UpdateStats};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
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
    pub per_task_success: Vec<f64>,
    pub mean_return: f64,
    pub episodes: usize,
}

/// Where a run is; passed to the progress callback after every evaluation and at the end.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainProgress {
    pub env_steps: u64,
    pub updates: u64,
    pub episodes: u64,
    pub wall_s: f64,
    /// Per task, success fraction over its last `success_window` training episodes.
    pub train_success: Vec<f64>,
    pub last_update: Option<UpdateStats>,
    pub eval: Option<EvalReport>,
    pub rejected_batches: u64,
    pub failed_updates: u64,
    /// Steps where the physics went unstable; they are not stored in replay.
    #[serde(default)]
    pub unstable_transitions: u64,
}

/// Summary of a finished run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    pub final_progress: TrainProgress,
    pub best_eval_success: f64,
    /// Transitions and seconds when `stop_at_eval_success` was first reached.
    pub reached_target_at_env_steps: Option<u64>,
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

/// Trains `sac` on `env`, evaluating on `eval_env`, until `total_env_steps` or the success target.
pub fn train<E: VecEnvironment, V: VecEnvironment>(
    sac: &mut Sac<f32>,
    env: &mut E,
    eval_env: &mut V,
    config: &TrainConfig,
    mut on_progress: impl FnMut(&TrainProgress, &Sac<f32>),
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
    let task_ids = env.task_ids().to_vec();
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut replay = MultiTaskReplay::new(nt, config.replay_capacity_per_task, od, ad);
    let mut batch = Batch::with_capacity(sc.batch_size, od, ad);
    let mut policy = Policy::new(sac.policy_spec(), n);
    let mut eval_policy = Policy::new(sac.policy_spec(), eval_env.num_envs());
    policy.set_params(&sac.policy_net().params, sac.updates())?;
    let mut obs = vec![0.0; n * od];
    let mut actions = vec![0.0; n * ad];
    let mut out = StepBuffers::new(n, od);
    env.reset_all(config.seed, &mut obs)
        .map_err(|e| SacError::Env(Box::new(e)))?;

    let mut progress = TrainProgress {
        train_success: vec![0.0; nt],
        ..Default::default()
    };
    let mut report = TrainReport::default();
    let mut windows: Vec<VecDeque<bool>> = vec![VecDeque::with_capacity(config.success_window); nt];
    let mut ep_success = vec![false; n];
    let (mut update_credit, mut failed_in_a_row) = (0.0f64, 0u64);
    let mut next_eval = if config.eval_every_env_steps > 0 {
        config.eval_every_env_steps
    } else {
        u64::MAX
    };
    let mut eval_round = 0u64;

    while progress.env_steps < config.total_env_steps {
        if progress.env_steps < config.warmup_env_steps {
            actions
                .iter_mut()
                .for_each(|a| *a = rng.gen_range(-1.0..1.0));
        } else {
            policy.act(&obs, &task_ids, false, &mut rng, &mut actions)?;
        }
        env.step(&actions, &mut out)
            .map_err(|e| SacError::Env(Box::new(e)))?;
        for i in 0..n {
            let t = task_ids[i];
            if out.unstable[i] {
                // Not a transition of the task (see `StepBuffers::unstable`): dropped, counted.
                progress.unstable_transitions += 1;
            } else {
                replay.push(
                    t,
                    &obs[i * od..(i + 1) * od],
                    &actions[i * ad..(i + 1) * ad],
                    out.reward[i],
                    &out.final_obs[i * od..(i + 1) * od],
                    out.terminated[i],
                );
            }
            ep_success[i] |= out.success[i];
            if out.terminated[i] || out.truncated[i] {
                progress.episodes += 1;
                let w = &mut windows[t];
                if w.len() == config.success_window.max(1) {
                    w.pop_front();
                }
                w.push_back(ep_success[i]);
                ep_success[i] = false;
            }
        }
        obs.copy_from_slice(&out.obs);
        progress.env_steps += n as u64;

        if progress.env_steps >= config.warmup_env_steps {
            update_credit += config.updates_per_vec_step;
            while update_credit >= 1.0 {
                update_credit -= 1.0;
                replay.sample_into(sc.batch_size, &mut rng, &mut batch);
                match sac.update(&batch) {
                    Ok(stats) => {
                        progress.last_update = Some(stats);
                        failed_in_a_row = 0;
                    }
                    Err(SacError::NonFiniteBatch { .. }) => {}
                    Err(
                        e @ (SacError::NonFiniteLoss { .. } | SacError::NonFiniteGradient { .. }),
                    ) => {
                        progress.failed_updates += 1;
                        failed_in_a_row += 1;
                        if failed_in_a_row >= config.max_consecutive_failed_updates {
                            return Err(e);
                        }
                    }
                    Err(e) => return Err(e),
                }
            }
            policy.set_params(&sac.policy_net().params, sac.updates())?;
        }

        let finished = progress.env_steps >= config.total_env_steps;
        if progress.env_steps >= next_eval || finished {
            next_eval = next_eval.saturating_add(config.eval_every_env_steps);
            eval_round += 1;
            eval_policy.set_params(&sac.policy_net().params, sac.updates())?;
            let eval_seed = config.seed.wrapping_add(1_000_003 * eval_round);
            let eval = evaluate(
                &mut eval_policy,
                eval_env,
                config.eval_episodes_per_env,
                eval_seed,
            )?;
            report.best_eval_success = report.best_eval_success.max(eval.success_rate);
            let reached = config
                .stop_at_eval_success
                .is_some_and(|t| eval.success_rate >= t);
            progress.eval = Some(eval);
            fill_progress(&mut progress, &windows, sac, start);
            on_progress(&progress, sac);
            if reached {
                report.reached_target_at_env_steps = Some(progress.env_steps);
                report.reached_target_at_wall_s = Some(progress.wall_s);
                break;
            }
        }
    }
    fill_progress(&mut progress, &windows, sac, start);
    report.final_progress = progress;
    Ok(report)
}

fn fill_progress(
    progress: &mut TrainProgress,
    windows: &[VecDeque<bool>],
    sac: &Sac<f32>,
    start: Instant,
) {
    progress.wall_s = start.elapsed().as_secs_f64();
    progress.updates = sac.updates();
    progress.rejected_batches = sac.rejected_batches();
    for (s, w) in progress.train_success.iter_mut().zip(windows) {
        *s = if w.is_empty() {
            0.0
        } else {
            w.iter().filter(|&&x| x).count() as f64 / w.len() as f64
        };
    }
}
