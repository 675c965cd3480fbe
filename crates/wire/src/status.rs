//! Status snapshots of the learner and the selector as plain, serialisable Rust values.
//!
//! Servers build these and convert them with `From`; clients get them through `TryFrom`, which
//! rejects non-finite or out-of-range numbers (a success rate of 1.7, a negative rate) with
//! `invalid_argument`, so `terl status` never prints garbage it received.

use serde::Serialize;
use tonic::Status;

use crate::pb;

/// Rolling success rate of one task.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct TaskSuccess {
    /// Meta-World v3 task name.
    pub task: String,
    /// In [0, 1].
    pub success_rate: f64,
    /// Episodes in the window.
    pub episodes: u64,
    /// Learner only: share of the task's env steps in the last window that were guided, [0, 1].
    pub guidance_rate: f64,
    /// Learner only, TERL: mean σ^N (Eq. 15) over the window's steps on which the planner could
    /// act (weights loaded, task validated), in [0, 1]; `None` when it could act on none.
    pub guidance_probability: Option<f64>,
    /// Learner only, TERL: of the window's steps that compared `f_t` with `f_{t−1}`, the share
    /// with `f_t ≥ f_{t−1}`, in [0, 1]; `None` without comparisons.
    pub not_improving_rate: Option<f64>,
    /// Learner only, TERL: mean `‖AN(s, g) − π(s)‖₂` over the window's guided steps, in action
    /// units, in [0, 4]; `None` without guided steps.
    pub action_gap: Option<f64>,
    /// Learner only, TERL: steps that compared `f_t` with `f_{t−1}` in the window.
    pub compared_steps: u64,
}

/// What one actor has delivered, as the learner sees it.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct ActorStats {
    /// The actor's id.
    pub actor_id: u32,
    /// Environment steps the learner has received from this actor.
    pub env_steps: u64,
    /// Its environment steps per second, last reporting window.
    pub env_steps_per_second: f64,
    /// Policy version of the actor's latest transitions.
    pub policy_version: u64,
    /// Seconds since the learner last heard from this actor.
    pub seconds_since_seen: f64,
    /// Transition batches (and transitions in them) that never reached the learner: the
    /// actor's send gave up on a full learner after `block_timeout_secs`. Cumulative over the
    /// actor's restarts; reported by the actor on its next delivered batch.
    pub transition_batches_dropped: u64,
    /// Transitions in those batches.
    pub transitions_dropped: u64,
    /// Finished episodes the actor could not deliver to every receiver (selector, learner).
    pub episodes_dropped: u64,
    /// Host name the actor gave when it subscribed to the weights; empty until it has.
    pub host: String,
    /// Address (`ip:port`) the actor's weight stream comes from, as the learner sees it.
    pub address: String,
}

/// One task's planner check (the guidance gate); see `PlannerTask` in `status.proto`.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct PlannerTask {
    /// Meta-World v3 task name.
    pub task: String,
    /// Spearman ρ of F on the task's held-out selected trajectories; `None` before a check.
    pub spearman: Option<f64>,
    /// Whether the task passed the check; guidance acts on it from then on (latched).
    pub validated: bool,
    /// TEP update count when it passed (0 while not validated).
    pub validated_at_tep_update: u64,
    /// Transitions of the task in the TEP buffer.
    pub tep_transitions: u64,
    /// Selected trajectories of the task held out for the check.
    pub held_out_trajectories: u64,
    /// Transitions in those trajectories.
    pub held_out_transitions: u64,
}

/// The planner side of the learner status, last window (`algorithm = "terl"`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct PlannerStatus {
    /// Mean of F's step term `(F(s_t, s_{t+1}, a_t) − 1)²`.
    pub step_loss: f64,
    /// Mean of F's hindsight term `(F(s_t, s', a_t) − z)²`.
    pub goal_loss: f64,
    /// Mean of F's symmetry term `(F(s_t, s_{t+1}, a_t) − F(s_{t+1}, s_t, −a_t))²`.
    pub symmetry_loss: f64,
    /// Mean of AN's behaviour-cloning term `‖AN(s_t, s') − a_t‖²`.
    pub an_bc_loss: f64,
    /// Mean hindsight gap `k` of the minibatches, env steps.
    pub gap_mean: f64,
    /// The guidance gate, one entry per task of the run.
    pub tasks: Vec<PlannerTask>,
}

fn planner_from_pb(m: pb::PlannerStatus) -> Result<PlannerStatus, Status> {
    let tasks = m
        .tasks
        .into_iter()
        .map(|t| {
            let rho = finite(&format!("planner.tasks[{}].spearman", t.task), t.spearman)?;
            Ok(PlannerTask {
                spearman: (-1.0..=1.0).contains(&rho).then_some(rho),
                validated: t.validated,
                validated_at_tep_update: t.validated_at_tep_update,
                tep_transitions: t.tep_transitions,
                held_out_trajectories: t.held_out_trajectories,
                held_out_transitions: t.held_out_transitions,
                task: t.task,
            })
        })
        .collect::<Result<_, Status>>()?;
    Ok(PlannerStatus {
        step_loss: non_negative("planner.step_loss", m.step_loss)?,
        goal_loss: non_negative("planner.goal_loss", m.goal_loss)?,
        symmetry_loss: non_negative("planner.symmetry_loss", m.symmetry_loss)?,
        an_bc_loss: non_negative("planner.an_bc_loss", m.an_bc_loss)?,
        gap_mean: non_negative("planner.gap_mean", m.gap_mean)?,
        tasks,
    })
}

fn planner_to_pb(d: PlannerStatus) -> pb::PlannerStatus {
    pb::PlannerStatus {
        step_loss: d.step_loss,
        goal_loss: d.goal_loss,
        symmetry_loss: d.symmetry_loss,
        an_bc_loss: d.an_bc_loss,
        gap_mean: d.gap_mean,
        tasks: d
            .tasks
            .into_iter()
            .map(|t| pb::PlannerTask {
                task: t.task,
                spearman: t.spearman.unwrap_or(-2.0),
                validated: t.validated,
                validated_at_tep_update: t.validated_at_tep_update,
                tep_transitions: t.tep_transitions,
                held_out_trajectories: t.held_out_trajectories,
                held_out_transitions: t.held_out_transitions,
            })
            .collect(),
    }
}

/// Training progress of the learner (`Learner.GetStatus`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct LearnerStatus {
    /// Run id (names the run folder and the shared-memory services).
    pub run_id: String,
    /// Seconds since the learner started.
    pub uptime_seconds: f64,
    /// MTSAC gradient updates done (TEP updates are counted in `tep_updates`).
    pub updates: u64,
    /// Updates per second over the last reporting window.
    pub updates_per_second: f64,
    /// Environment steps received from all actors.
    pub env_steps_total: u64,
    /// Per actor: what it has delivered.
    pub actors: Vec<ActorStats>,
    /// Transitions held in replay, over all tasks.
    pub replay_size: u64,
    /// Replay capacity, over all tasks.
    pub replay_capacity: u64,
    /// Per task: the rolling training success window.
    pub task_success: Vec<TaskSuccess>,
    /// Updates between the policy that produced trained-on transitions and the current one.
    pub staleness_mean: f64,
    /// Largest staleness over the last window, updates.
    pub staleness_max: u64,
    /// Transition batches refused (bad shape, non-finite values, unknown task, too stale).
    pub rejected_batches: u64,
    /// Latest published policy version (0 = none yet).
    pub policy_version: u64,
    /// Latest published planner version (0 = none yet).
    pub planner_version: u64,
    /// TEP updates done (0 when `algorithm = "mtsac"`).
    pub tep_updates: u64,
    /// `mtsac` or `terl`.
    pub algorithm: String,
    /// Selected transitions held in the TEP buffer.
    pub tep_buffer_size: u64,
    /// TEP buffer capacity, transitions.
    pub tep_buffer_capacity: u64,
    /// Mean F loss over the last window (0 before the first TEP update).
    pub tep_f_loss: f64,
    /// Mean AN loss over the last window (0 before the first TEP update).
    pub tep_an_loss: f64,
    /// Selected transitions received (from the selector or a loaded dataset).
    pub selected_samples: u64,
    /// Selected transitions kept out of the TEP buffer because they came after their
    /// trajectory's first success.
    pub tep_after_success: u64,
    /// Env steps executed with the Action Network, all actors.
    pub guided_steps: u64,
    /// Mean bootstrapped TEP target `1 + F̃(..)` over the last window, in env steps (≥ 1; 0
    /// before the first TEP update).
    pub tep_target_mean: f64,
    /// Mean predicted distance `F(s_t, s', a_t)` to the hindsight goal over the last window, in
    /// env steps (≥ 0).
    pub tep_goal_distance_mean: f64,
    /// Transition batches that never reached the learner (an actor's send gave up on a full
    /// learner), summed over [`ActorStats`].
    pub transition_batches_dropped: u64,
    /// Transitions in those batches, summed over actors.
    pub transitions_dropped: u64,
    /// Finished episodes not delivered to every receiver, summed over actors.
    pub episodes_dropped: u64,
    /// Selected batches the selector could not deliver (the learner stayed full).
    pub selected_batches_dropped: u64,
    /// Samples in those batches.
    pub selected_samples_dropped: u64,
    /// The checkpoint a resumed learner continued from (empty: a fresh start).
    pub resumed_from: String,
    /// That checkpoint's update count (0: a fresh start).
    pub resumed_at_update: u64,
    /// Checkpoints that could not be written since this learner started.
    pub checkpoint_failures: u64,
    /// Transition batches lost in transit: gaps in the actors' sequence numbers, summed.
    pub transition_batches_missed: u64,
    /// Updates/s of a fresh copy of the learner's networks timed alone at start (0: not timed).
    pub standalone_updates_per_second: f64,
    /// Updates per second of time spent inside updates, last rate window.
    pub busy_updates_per_second: f64,
    /// `busy / standalone` (0 when either is unknown).
    pub update_speed_ratio: f64,
    /// Longest staging round of the last rate window, ms.
    pub staging_max_ms: f64,
    /// `algorithm = "terl"`: planner losses and the guidance gate per task.
    pub planner: PlannerStatus,
}

/// Statistics of PTR priorities.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct PriorityStats {
    /// Transitions scored.
    pub scored: u64,
    /// Mean priority of the scored transitions.
    pub mean: f64,
    /// Smallest priority.
    pub min: f64,
    /// Largest priority.
    pub max: f64,
    /// Priority of the lowest-ranked transition that was still selected.
    pub selection_threshold: f64,
    /// Mean over the scored transitions of the GAE part `α · mean(GAE)` of the priority.
    pub gae_part_mean: f64,
    /// Mean over the scored transitions of the entropy part `(1 − α) · H` (with the GAE part,
    /// the mean priority).
    pub entropy_part_mean: f64,
}

/// Episode and selection statistics of the selector (`Selector.GetStatus`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct SelectorStatus {
    /// Run id (names the run folder and the shared-memory services).
    pub run_id: String,
    /// Seconds since the selector started.
    pub uptime_seconds: f64,
    /// Finished episodes received from the actors.
    pub episodes_seen: u64,
    /// Per task: the rolling success window the selection gate looks at.
    pub task_success: Vec<TaskSuccess>,
    /// Transitions sent to the learner's TEP buffer.
    pub selected_samples: u64,
    /// PTR priorities of the scored transitions (all zero before any scoring).
    pub priority: PriorityStats,
    /// Critic version the priorities were last computed with (0 = none).
    pub critic_version: u64,
    /// The latest in-run evaluation (None before the first one or with evaluation off).
    pub last_eval: Option<EvalResult>,
    /// Evaluations finished since the selector started.
    pub evaluations: u64,
    /// Episodes the actors report they could not deliver to every receiver, summed.
    pub episodes_dropped: u64,
    /// Episodes this selector never received (gaps in each actor's episode indices).
    pub episodes_missed: u64,
}

/// One task's part of an [`EvalResult`].
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct TaskEval {
    /// Meta-World v3 task name.
    pub task: String,
    /// Episodes with success at any step / episodes, in [0, 1].
    pub success_rate: f64,
    /// Mean undiscounted episode return.
    pub mean_return: f64,
    /// Mean 1-based first-success step over successful episodes (None: none succeeded).
    pub mean_first_success_step: Option<f64>,
    /// Episodes run on the task.
    pub episodes: u32,
}

/// One deterministic evaluation of one policy version on every task of a run
/// (`terl.v1.EvalResult`; the protocol is `terl_runtime::eval`'s): served by the selector and
/// logged to `runs/<id>/eval.mcap`.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct EvalResult {
    /// Policy version (learner update count) evaluated.
    pub policy_version: u64,
    /// Env steps the learner had received when the evaluation started.
    pub env_steps: u64,
    /// Episodes per task (episode `k` runs on goal variation `k mod 50`).
    pub episodes_per_task: u32,
    /// Unweighted mean of the per-task success rates, in [0, 1].
    pub mean_success_rate: f64,
    /// Unweighted mean over tasks of [`TaskEval::mean_return`].
    pub mean_return: f64,
    /// Per task results, in the run's task order.
    pub tasks: Vec<TaskEval>,
    /// Wall-clock seconds the evaluation took (its cost to the run).
    pub wall_seconds: f64,
    /// CPU seconds the evaluation took.
    pub cpu_seconds: f64,
    /// When the evaluation finished, nanoseconds since the Unix epoch.
    pub unix_time_nanos: u64,
}

impl EvalResult {
    /// The evaluation as scalar metrics, cleanrl-style names as in the issue tracker's
    /// protocol: `eval/mean_success_rate`, `eval/mean_return`, `eval/success_rate/<task>`,
    /// `eval/return/<task>`, `eval/first_success_step/<task>` (successful tasks only),
    /// `eval/env_steps`, `eval/wall_seconds`, `eval/cpu_seconds`; each is logged at step =
    /// [`EvalResult::policy_version`].
    pub fn metrics(&self) -> Vec<(String, f64)> {
        let mut out = vec![
            ("eval/mean_success_rate".to_string(), self.mean_success_rate),
            ("eval/mean_return".to_string(), self.mean_return),
            ("eval/env_steps".to_string(), self.env_steps as f64),
            ("eval/wall_seconds".to_string(), self.wall_seconds),
            ("eval/cpu_seconds".to_string(), self.cpu_seconds),
        ];
        for t in &self.tasks {
            out.push((format!("eval/success_rate/{}", t.task), t.success_rate));
            out.push((format!("eval/return/{}", t.task), t.mean_return));
            if let Some(f) = t.mean_first_success_step {
                out.push((format!("eval/first_success_step/{}", t.task), f));
            }
        }
        out
    }
}

impl TryFrom<pb::TaskEval> for TaskEval {
    type Error = Status;
    fn try_from(m: pb::TaskEval) -> Result<Self, Status> {
        let rate = non_negative("success_rate", m.success_rate)?;
        if rate > 1.0 {
            return Err(Status::invalid_argument(format!(
                "success_rate of {} is {rate}, above 1",
                m.task
            )));
        }
        let first = non_negative("mean_first_success_step", m.mean_first_success_step)?;
        Ok(Self {
            task: m.task,
            success_rate: rate,
            mean_return: finite("mean_return", m.mean_return)?,
            mean_first_success_step: (first > 0.0).then_some(first),
            episodes: m.episodes,
        })
    }
}

impl From<TaskEval> for pb::TaskEval {
    fn from(d: TaskEval) -> Self {
        Self {
            task: d.task,
            success_rate: d.success_rate,
            mean_return: d.mean_return,
            mean_first_success_step: d.mean_first_success_step.unwrap_or(0.0),
            episodes: d.episodes,
        }
    }
}

impl TryFrom<pb::EvalResult> for EvalResult {
    type Error = Status;
    fn try_from(m: pb::EvalResult) -> Result<Self, Status> {
        let rate = non_negative("mean_success_rate", m.mean_success_rate)?;
        if rate > 1.0 {
            return Err(Status::invalid_argument(format!(
                "mean_success_rate is {rate}, above 1"
            )));
        }
        Ok(Self {
            policy_version: m.policy_version,
            env_steps: m.env_steps,
            episodes_per_task: m.episodes_per_task,
            mean_success_rate: rate,
            mean_return: finite("mean_return", m.mean_return)?,
            tasks: convert_all(m.tasks)?,
            wall_seconds: non_negative("wall_seconds", m.wall_seconds)?,
            cpu_seconds: non_negative("cpu_seconds", m.cpu_seconds)?,
            unix_time_nanos: m.unix_time_nanos,
        })
    }
}

impl From<EvalResult> for pb::EvalResult {
    fn from(d: EvalResult) -> Self {
        Self {
            policy_version: d.policy_version,
            env_steps: d.env_steps,
            episodes_per_task: d.episodes_per_task,
            mean_success_rate: d.mean_success_rate,
            mean_return: d.mean_return,
            tasks: d.tasks.into_iter().map(Into::into).collect(),
            wall_seconds: d.wall_seconds,
            cpu_seconds: d.cpu_seconds,
            unix_time_nanos: d.unix_time_nanos,
        }
    }
}

fn finite(field: &str, value: f64) -> Result<f64, Status> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Status::invalid_argument(format!(
            "{field} is not finite ({value})"
        )))
    }
}

fn non_negative(field: &str, value: f64) -> Result<f64, Status> {
    if finite(field, value)? >= 0.0 {
        Ok(value)
    } else {
        Err(Status::invalid_argument(format!(
            "{field} is negative ({value})"
        )))
    }
}

/// Longest host name or address accepted in a status message (a DNS name is at most 253).
pub const MAX_HOST_BYTES: usize = 255;

fn bounded_text(field: &str, value: String) -> Result<String, Status> {
    if value.len() <= MAX_HOST_BYTES {
        Ok(value)
    } else {
        Err(Status::invalid_argument(format!(
            "{field} is {} bytes, the limit is {MAX_HOST_BYTES}",
            value.len()
        )))
    }
}

impl TryFrom<pb::TaskSuccess> for TaskSuccess {
    type Error = Status;
    fn try_from(m: pb::TaskSuccess) -> Result<Self, Status> {
        if m.task.is_empty() {
            return Err(Status::invalid_argument("task_success: empty task name"));
        }
        let field = format!("task_success[{}].success_rate", m.task);
        if !(0.0..=1.0).contains(&finite(&field, m.success_rate)?) {
            return Err(Status::invalid_argument(format!(
                "{field} is outside [0, 1] ({})",
                m.success_rate
            )));
        }
        let field = format!("task_success[{}].guidance_rate", m.task);
        if !(0.0..=1.0).contains(&finite(&field, m.guidance_rate)?) {
            return Err(Status::invalid_argument(format!(
                "{field} is outside [0, 1] ({})",
                m.guidance_rate
            )));
        }
        let within = |name: &str, v: Option<f64>, hi: f64| -> Result<Option<f64>, Status> {
            let Some(v) = v else { return Ok(None) };
            let field = format!("task_success[{}].{name}", m.task);
            if !(0.0..=hi).contains(&finite(&field, v)?) {
                return Err(Status::invalid_argument(format!(
                    "{field} is outside [0, {hi}] ({v})"
                )));
            }
            Ok(Some(v))
        };
        Ok(Self {
            guidance_probability: within("guidance_probability", m.guidance_probability, 1.0)?,
            not_improving_rate: within("not_improving_rate", m.not_improving_rate, 1.0)?,
            action_gap: within("action_gap", m.action_gap, 4.0)?,
            compared_steps: m.compared_steps,
            task: m.task,
            success_rate: m.success_rate,
            episodes: m.episodes,
            guidance_rate: m.guidance_rate,
        })
    }
}

impl From<TaskSuccess> for pb::TaskSuccess {
    fn from(d: TaskSuccess) -> Self {
        Self {
            task: d.task,
            success_rate: d.success_rate,
            episodes: d.episodes,
            guidance_rate: d.guidance_rate,
            guidance_probability: d.guidance_probability,
            not_improving_rate: d.not_improving_rate,
            action_gap: d.action_gap,
            compared_steps: d.compared_steps,
        }
    }
}

impl TryFrom<pb::ActorStats> for ActorStats {
    type Error = Status;
    fn try_from(m: pb::ActorStats) -> Result<Self, Status> {
        let id = m.actor_id;
        Ok(Self {
            actor_id: id,
            env_steps: m.env_steps,
            env_steps_per_second: non_negative(
                &format!("actors[{id}].env_steps_per_second"),
                m.env_steps_per_second,
            )?,
            policy_version: m.policy_version,
            seconds_since_seen: non_negative(
                &format!("actors[{id}].seconds_since_seen"),
                m.seconds_since_seen,
            )?,
            transition_batches_dropped: m.transition_batches_dropped,
            transitions_dropped: m.transitions_dropped,
            episodes_dropped: m.episodes_dropped,
            host: bounded_text(&format!("actors[{id}].host"), m.host)?,
            address: bounded_text(&format!("actors[{id}].address"), m.address)?,
        })
    }
}

impl From<ActorStats> for pb::ActorStats {
    fn from(d: ActorStats) -> Self {
        Self {
            actor_id: d.actor_id,
            env_steps: d.env_steps,
            env_steps_per_second: d.env_steps_per_second,
            policy_version: d.policy_version,
            seconds_since_seen: d.seconds_since_seen,
            transition_batches_dropped: d.transition_batches_dropped,
            transitions_dropped: d.transitions_dropped,
            episodes_dropped: d.episodes_dropped,
            host: d.host,
            address: d.address,
        }
    }
}

fn convert_all<P, D: TryFrom<P, Error = Status>>(items: Vec<P>) -> Result<Vec<D>, Status> {
    items.into_iter().map(D::try_from).collect()
}

impl TryFrom<pb::LearnerStatus> for LearnerStatus {
    type Error = Status;
    fn try_from(m: pb::LearnerStatus) -> Result<Self, Status> {
        if m.replay_size > m.replay_capacity {
            return Err(Status::invalid_argument(format!(
                "replay_size {} exceeds replay_capacity {}",
                m.replay_size, m.replay_capacity
            )));
        }
        if m.tep_buffer_size > m.tep_buffer_capacity {
            return Err(Status::invalid_argument(format!(
                "tep_buffer_size {} exceeds tep_buffer_capacity {}",
                m.tep_buffer_size, m.tep_buffer_capacity
            )));
        }
        Ok(Self {
            run_id: m.run_id,
            uptime_seconds: non_negative("uptime_seconds", m.uptime_seconds)?,
            updates: m.updates,
            updates_per_second: non_negative("updates_per_second", m.updates_per_second)?,
            env_steps_total: m.env_steps_total,
            actors: convert_all(m.actors)?,
            replay_size: m.replay_size,
            replay_capacity: m.replay_capacity,
            task_success: convert_all(m.task_success)?,
            staleness_mean: non_negative("staleness_mean", m.staleness_mean)?,
            staleness_max: m.staleness_max,
            rejected_batches: m.rejected_batches,
            policy_version: m.policy_version,
            planner_version: m.planner_version,
            tep_updates: m.tep_updates,
            algorithm: m.algorithm,
            tep_buffer_size: m.tep_buffer_size,
            tep_buffer_capacity: m.tep_buffer_capacity,
            tep_f_loss: finite("tep_f_loss", m.tep_f_loss)?,
            tep_an_loss: finite("tep_an_loss", m.tep_an_loss)?,
            selected_samples: m.selected_samples,
            tep_after_success: m.tep_after_success,
            guided_steps: m.guided_steps,
            tep_target_mean: non_negative("tep_target_mean", m.tep_target_mean)?,
            tep_goal_distance_mean: non_negative(
                "tep_goal_distance_mean",
                m.tep_goal_distance_mean,
            )?,
            transition_batches_dropped: m.transition_batches_dropped,
            transitions_dropped: m.transitions_dropped,
            episodes_dropped: m.episodes_dropped,
            selected_batches_dropped: m.selected_batches_dropped,
            selected_samples_dropped: m.selected_samples_dropped,
            resumed_from: m.resumed_from,
            resumed_at_update: m.resumed_at_update,
            checkpoint_failures: m.checkpoint_failures,
            transition_batches_missed: m.transition_batches_missed,
            standalone_updates_per_second: m.standalone_updates_per_second,
            busy_updates_per_second: m.busy_updates_per_second,
            update_speed_ratio: m.update_speed_ratio,
            staging_max_ms: m.staging_max_ms,
            planner: planner_from_pb(m.planner.unwrap_or_default())?,
        })
    }
}

impl From<LearnerStatus> for pb::LearnerStatus {
    fn from(d: LearnerStatus) -> Self {
        Self {
            run_id: d.run_id,
            uptime_seconds: d.uptime_seconds,
            updates: d.updates,
            updates_per_second: d.updates_per_second,
            env_steps_total: d.env_steps_total,
            actors: d.actors.into_iter().map(Into::into).collect(),
            replay_size: d.replay_size,
            replay_capacity: d.replay_capacity,
            task_success: d.task_success.into_iter().map(Into::into).collect(),
            staleness_mean: d.staleness_mean,
            staleness_max: d.staleness_max,
            rejected_batches: d.rejected_batches,
            policy_version: d.policy_version,
            planner_version: d.planner_version,
            tep_updates: d.tep_updates,
            algorithm: d.algorithm,
            tep_buffer_size: d.tep_buffer_size,
            tep_buffer_capacity: d.tep_buffer_capacity,
            tep_f_loss: d.tep_f_loss,
            tep_an_loss: d.tep_an_loss,
            selected_samples: d.selected_samples,
            tep_after_success: d.tep_after_success,
            guided_steps: d.guided_steps,
            tep_target_mean: d.tep_target_mean,
            tep_goal_distance_mean: d.tep_goal_distance_mean,
            transition_batches_dropped: d.transition_batches_dropped,
            transitions_dropped: d.transitions_dropped,
            episodes_dropped: d.episodes_dropped,
            selected_batches_dropped: d.selected_batches_dropped,
            selected_samples_dropped: d.selected_samples_dropped,
            resumed_from: d.resumed_from,
            resumed_at_update: d.resumed_at_update,
            checkpoint_failures: d.checkpoint_failures,
            transition_batches_missed: d.transition_batches_missed,
            standalone_updates_per_second: d.standalone_updates_per_second,
            busy_updates_per_second: d.busy_updates_per_second,
            update_speed_ratio: d.update_speed_ratio,
            staging_max_ms: d.staging_max_ms,
            planner: Some(planner_to_pb(d.planner)),
        }
    }
}

impl TryFrom<pb::PriorityStats> for PriorityStats {
    type Error = Status;
    fn try_from(m: pb::PriorityStats) -> Result<Self, Status> {
        let s = Self {
            scored: m.scored,
            mean: finite("priority.mean", m.mean)?,
            min: finite("priority.min", m.min)?,
            max: finite("priority.max", m.max)?,
            selection_threshold: finite("priority.selection_threshold", m.selection_threshold)?,
            gae_part_mean: finite("priority.gae_part_mean", m.gae_part_mean)?,
            entropy_part_mean: finite("priority.entropy_part_mean", m.entropy_part_mean)?,
        };
        if s.scored > 0 && !(s.min <= s.mean && s.mean <= s.max) {
            return Err(Status::invalid_argument(format!(
                "priority: expected min <= mean <= max, got {} / {} / {}",
                s.min, s.mean, s.max
            )));
        }
        Ok(s)
    }
}

impl From<PriorityStats> for pb::PriorityStats {
    fn from(d: PriorityStats) -> Self {
        Self {
            scored: d.scored,
            mean: d.mean,
            min: d.min,
            max: d.max,
            selection_threshold: d.selection_threshold,
            gae_part_mean: d.gae_part_mean,
            entropy_part_mean: d.entropy_part_mean,
        }
    }
}

impl TryFrom<pb::SelectorStatus> for SelectorStatus {
    type Error = Status;
    fn try_from(m: pb::SelectorStatus) -> Result<Self, Status> {
        Ok(Self {
            run_id: m.run_id,
            uptime_seconds: non_negative("uptime_seconds", m.uptime_seconds)?,
            episodes_seen: m.episodes_seen,
            task_success: convert_all(m.task_success)?,
            selected_samples: m.selected_samples,
            // A missing sub-message means "nothing scored yet".
            priority: m
                .priority
                .map(PriorityStats::try_from)
                .transpose()?
                .unwrap_or_default(),
            critic_version: m.critic_version,
            last_eval: m.last_eval.map(EvalResult::try_from).transpose()?,
            evaluations: m.evaluations,
            episodes_dropped: m.episodes_dropped,
            episodes_missed: m.episodes_missed,
        })
    }
}

impl From<SelectorStatus> for pb::SelectorStatus {
    fn from(d: SelectorStatus) -> Self {
        Self {
            run_id: d.run_id,
            uptime_seconds: d.uptime_seconds,
            episodes_seen: d.episodes_seen,
            task_success: d.task_success.into_iter().map(Into::into).collect(),
            selected_samples: d.selected_samples,
            priority: Some(d.priority.into()),
            critic_version: d.critic_version,
            last_eval: d.last_eval.map(Into::into),
            evaluations: d.evaluations,
            episodes_dropped: d.episodes_dropped,
            episodes_missed: d.episodes_missed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_out_of_range_numbers() {
        let mut m = pb::LearnerStatus {
            replay_capacity: 10,
            task_success: vec![pb::TaskSuccess {
                task: "reach".into(),
                success_rate: 1.5,
                episodes: 3,
                ..Default::default()
            }],
            ..Default::default()
        };
        let e = LearnerStatus::try_from(m.clone()).unwrap_err();
        assert!(e
            .message()
            .contains("task_success[reach].success_rate is outside [0, 1]"));
        m.task_success[0].success_rate = 0.5;
        m.task_success[0].guidance_rate = -0.1;
        let e = LearnerStatus::try_from(m.clone()).unwrap_err();
        assert!(e
            .message()
            .contains("task_success[reach].guidance_rate is outside [0, 1]"));
        m.task_success[0].guidance_rate = 0.25;
        m.task_success[0].action_gap = Some(4.5);
        let e = LearnerStatus::try_from(m.clone()).unwrap_err();
        assert!(
            e.message()
                .contains("task_success[reach].action_gap is outside [0, 4]"),
            "{}",
            e.message()
        );
        m.task_success[0].action_gap = None;
        m.task_success[0].not_improving_rate = Some(f64::NAN);
        let e = LearnerStatus::try_from(m.clone()).unwrap_err();
        assert!(
            e.message().contains("not_improving_rate"),
            "{}",
            e.message()
        );
        m.task_success[0].not_improving_rate = Some(0.5);
        m.task_success[0].guidance_probability = Some(-0.5);
        let e = LearnerStatus::try_from(m.clone()).unwrap_err();
        assert!(
            e.message().contains("guidance_probability"),
            "{}",
            e.message()
        );
        m.task_success[0].guidance_probability = Some(0.9);
        assert_eq!(
            LearnerStatus::try_from(m.clone()).unwrap().task_success[0].not_improving_rate,
            Some(0.5)
        );
        m.updates_per_second = f64::NAN;
        let e = LearnerStatus::try_from(m.clone()).unwrap_err();
        assert_eq!(e.message(), "updates_per_second is not finite (NaN)");
        m.updates_per_second = 1.0;
        m.replay_size = 11;
        assert!(LearnerStatus::try_from(m)
            .unwrap_err()
            .message()
            .contains("exceeds"));
    }

    #[test]
    fn selector_without_priority_is_default() {
        let s = SelectorStatus::try_from(pb::SelectorStatus::default()).unwrap();
        assert_eq!(s.priority, PriorityStats::default());
    }
}
