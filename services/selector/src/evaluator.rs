//! The in-run evaluator: a thread of the selector that, every `train.eval_every_env_steps`
//! env steps the learner received, runs the latest policy version it follows deterministically
//! on `cluster.eval_episodes_per_task` goal variations of every task
//! ([`terl_runtime::eval::evaluate_policy`], the protocol of `terl eval`), appends the result to
//! `runs/<id>/eval.mcap` (`terl.v1.EvalResult` on `/eval`) and serves the latest one in the
//! selector's status.
//!
//! Why in the selector and not a process of its own: the selector already follows the
//! learner's weight stream and serves a status that `terl status` reads, and it is idle most of
//! the time (it receives one summary per finished episode), so an evaluator thread there costs
//! no extra process, connection or launcher step. Its CPU time competes with the actors on a
//! small machine, so the episodes per task and the threads are config values (default 10
//! episodes, 1 thread) and every evaluation logs its wall and CPU seconds. The thread keeps its
//! environments ([`EvalEnvs`]) between evaluations, so the selector's memory stays at one
//! evaluation's footprint over a long run.

use std::sync::atomic::Ordering;
use std::time::Duration;

use terl_runtime::eval::{
    evaluate_policy_with, plan_tasks, EvalEnvs, EvalSettings, UnseenTaskEncoding,
};
use terl_wire::{EvalResult, TaskEval};

use crate::{SelectorConfig, Shared};

/// How often the evaluator asks the learner for its env-step count.
const POLL: Duration = Duration::from_millis(500);

/// Runs until `shared.stop`; errors of one evaluation are logged and the next one is tried.
#[allow(clippy::too_many_lines)] // the evaluator thread's set-up and loop in one place
pub(crate) fn run(config: &SelectorConfig, shared: &Shared, learner_addr: &str) {
    let run = &config.run;
    let every = run.train.eval_every_env_steps;
    let tasks = match terl_runtime::resolve_tasks(&run.tasks) {
        Ok(t) => t,
        Err(e) => {
            tracing::error!("evaluator: {e:#}");
            return;
        }
    };
    let plan = plan_tasks(&tasks, &tasks, UnseenTaskEncoding::Uniform);
    let sac = run.sac_config(tasks.len());
    let mut policy = terl_rl::Policy::new(terl_rl::PolicySpec::from_config(&sac), 1);
    let settings = EvalSettings {
        episodes_per_task: run.cluster.eval_episodes_per_task,
        variation_seed: run.variation_seed,
        threads: run.cluster.eval_threads,
        batch: run.cluster.eval_envs_per_task,
    };
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            tracing::error!("evaluator: no runtime: {e}");
            return;
        }
    };
    tracing::info!(
        every_env_steps = every,
        episodes_per_task = settings.episodes_per_task,
        threads = settings.threads,
        "evaluator started"
    );
    // Built on the first evaluation and kept for the life of the thread: rebuilding the MuJoCo
    // environments for every evaluation grew the process by hundreds of MB each time.
    let envs = EvalEnvs::default();
    let mut client = None;
    let mut next = every;
    while !shared.stop.load(Ordering::Relaxed) {
        std::thread::sleep(POLL);
        let status = rt.block_on(async {
            tokio::time::timeout(Duration::from_secs(5), async {
                if client.is_none() {
                    let options = terl_wire::ClientOptions::secured(config.client_security.clone());
                    client = Some(terl_wire::connect_learner_with(learner_addr, options).await?);
                }
                let c = client.as_mut().expect("connected above");
                anyhow::Ok(c.status().await?)
            })
            .await
            .map_err(anyhow::Error::from)
            .and_then(|r| r)
        });
        let env_steps = match status {
            Ok(s) => s.env_steps_total,
            Err(e) => {
                tracing::debug!("evaluator: learner status: {e:#}");
                client = None;
                continue;
            }
        };
        if env_steps < next {
            continue;
        }
        let Some((version, params)) = shared.eval_policy.lock().ok().and_then(|p| p.clone()) else {
            continue;
        };
        if let Err(e) = policy.set_params(&params, version) {
            tracing::warn!(version, "evaluator: ignoring policy weights: {e}");
            continue;
        }
        next = (env_steps / every + 1) * every;
        let summary = match evaluate_policy_with(
            &envs,
            &policy,
            &plan,
            &settings,
            &|_| {},
            Some(&shared.stop),
        ) {
            Ok(s) => s,
            Err(terl_runtime::eval::EvalError::Cancelled) => break,
            Err(e) => {
                tracing::warn!(version, "evaluation failed: {e}");
                continue;
            }
        };
        let result = EvalResult {
            policy_version: summary.policy_version,
            env_steps,
            episodes_per_task: summary.episodes_per_task as u32,
            mean_success_rate: summary.mean_success_rate,
            mean_return: summary.mean_return,
            tasks: summary
                .tasks
                .iter()
                .map(|t| TaskEval {
                    task: t.task.clone(),
                    success_rate: t.success_rate,
                    mean_return: t.mean_return,
                    mean_first_success_step: t.mean_first_success_step,
                    episodes: t.episodes as u32,
                })
                .collect(),
            wall_seconds: summary.wall_seconds,
            cpu_seconds: summary.cpu_seconds.unwrap_or(0.0),
            unix_time_nanos: terl_telemetry::unix_nanos(),
        };
        tracing::info!(
            policy_version = result.policy_version,
            env_steps,
            mean_success_rate = result.mean_success_rate,
            mean_return = result.mean_return,
            episodes = summary.episodes_per_task * summary.tasks.len(),
            wall_seconds = result.wall_seconds,
            cpu_seconds = result.cpu_seconds,
            "evaluation"
        );
        if let Ok(mut log) = shared.eval_log.lock() {
            if let Some(w) = log.as_mut() {
                if let Err(e) = w
                    .write(&result, result.unix_time_nanos)
                    .and_then(|()| w.flush())
                {
                    tracing::warn!("evaluation not logged: {e}");
                }
            }
        }
        if let Ok(mut tb) = shared.eval_tensorboard.lock() {
            if let Some(w) = tb.as_mut() {
                let metrics = result.metrics();
                let seconds = result.unix_time_nanos as f64 / 1e9;
                let values = metrics.iter().map(|(k, v)| (k.as_str(), *v));
                if let Err(e) = w.scalars(result.env_steps, seconds, values) {
                    tracing::warn!("evaluation not written for TensorBoard: {e}");
                }
            }
        }
        if let Ok(mut last) = shared.last_eval.lock() {
            last.0 = Some(result);
            last.1 += 1;
        }
    }
}
