//! Records of the MCAP logs (TEP dataset, episode summaries, metrics) with edge validation.
//!
//! The MCAP writers in `crates/telemetry` encode the `pb` messages; readers turn them back into
//! these types, so a dataset written by an older or buggy run is rejected on load with a precise
//! message instead of training the planner on garbage.

use serde::Serialize;
use tonic::Status;

use crate::pb;

/// Meta-World observation and action widths (defined once, in `terl_spaces`).
pub use terl_spaces::{ACTION_DIM, OBS_DIM};

/// One transition selected for the TEP dataset.
#[derive(Debug, Clone, PartialEq)]
pub struct TepSample {
    /// Meta-World v3 task name, e.g. `"pick-place-v3"` (never empty).
    pub task: String,
    /// Identifies the trajectory within a run; hindsight goals are drawn from later steps of the
    /// same trajectory.
    pub trajectory_id: u64,
    /// Step index within the trajectory, from 0.
    pub step: u32,
    /// PTR priority `P` of the batch the sample was ranked in (finite).
    pub priority: f64,
    /// Observation `s_t` (Meta-World's 39 values, finite).
    pub obs: [f32; OBS_DIM],
    /// Observation `s_{t+1}` reached by `action`.
    pub next_obs: [f32; OBS_DIM],
    /// `None` when the sample was recorded without a goal state.
    pub goal_obs: Option<[f32; OBS_DIM]>,
    /// Action `a_t`, each entry in `[-1, 1]`.
    pub action: [f32; ACTION_DIM],
    /// Meta-World's success flag after this step (`false` when not recorded).
    pub success: bool,
    /// Goal-variation index (0..50) of the trajectory, when the writer knew it.
    pub variation: Option<u32>,
}

fn fixed<const N: usize>(field: &str, values: &[f32]) -> Result<[f32; N], Status> {
    let array: [f32; N] = values.try_into().map_err(|_| {
        Status::invalid_argument(format!(
            "{field}: expected {N} values, got {}",
            values.len()
        ))
    })?;
    if let Some(i) = array.iter().position(|v| !v.is_finite()) {
        return Err(Status::invalid_argument(format!(
            "{field}[{i}] is not finite ({})",
            array[i]
        )));
    }
    Ok(array)
}

impl TryFrom<pb::TepSample> for TepSample {
    type Error = Status;
    fn try_from(m: pb::TepSample) -> Result<Self, Status> {
        if m.task.is_empty() {
            return Err(Status::invalid_argument("TepSample: empty task name"));
        }
        let action: [f32; ACTION_DIM] = fixed("TepSample.action", &m.action)?;
        if let Some(i) = action.iter().position(|a| a.abs() > 1.0) {
            return Err(Status::invalid_argument(format!(
                "TepSample.action[{i}] = {} is outside [-1, 1]",
                action[i]
            )));
        }
        if !m.priority.is_finite() {
            return Err(Status::invalid_argument(format!(
                "TepSample.priority is not finite ({})",
                m.priority
            )));
        }
        Ok(Self {
            obs: fixed("TepSample.obs", &m.obs)?,
            next_obs: fixed("TepSample.next_obs", &m.next_obs)?,
            goal_obs: if m.goal_obs.is_empty() {
                None
            } else {
                Some(fixed("TepSample.goal_obs", &m.goal_obs)?)
            },
            action,
            success: m.success,
            variation: m.variation,
            task: m.task,
            trajectory_id: m.trajectory_id,
            step: m.step,
            priority: m.priority,
        })
    }
}

impl From<TepSample> for pb::TepSample {
    fn from(d: TepSample) -> Self {
        Self {
            task: d.task,
            trajectory_id: d.trajectory_id,
            step: d.step,
            priority: d.priority,
            obs: d.obs.to_vec(),
            next_obs: d.next_obs.to_vec(),
            goal_obs: d.goal_obs.map(|g| g.to_vec()).unwrap_or_default(),
            action: d.action.to_vec(),
            success: d.success,
            variation: d.variation,
        }
    }
}

/// For writers that keep the sample (the MCAP dataset writer encodes borrowed samples).
impl From<&TepSample> for pb::TepSample {
    fn from(d: &TepSample) -> Self {
        Self {
            task: d.task.clone(),
            trajectory_id: d.trajectory_id,
            step: d.step,
            priority: d.priority,
            obs: d.obs.to_vec(),
            next_obs: d.next_obs.to_vec(),
            goal_obs: d.goal_obs.map(|g| g.to_vec()).unwrap_or_default(),
            action: d.action.to_vec(),
            success: d.success,
            variation: d.variation,
        }
    }
}

/// One finished episode.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EpisodeSummary {
    /// Meta-World v3 task name (never empty).
    pub task: String,
    /// Id of the actor that ran the episode.
    pub actor_id: u32,
    /// The episode's index among the actor's episodes; a gap shows up as `missed_before`.
    pub episode_index: u64,
    /// Sum of the episode's rewards (finite).
    pub episode_return: f64,
    /// Success at any step (Meta-World's rule).
    pub success: bool,
    /// Steps of the episode, env steps (Meta-World truncates at 500).
    pub length: u32,
    /// Version of the policy the episode began with.
    pub policy_version: u64,
    /// Steps executed with the Action Network instead of the policy (TERL guidance); at most
    /// `length`.
    pub guided_steps: u32,
    /// Episodes of this actor the log's writer never received just before this one (a gap in
    /// `episode_index`); 0 normally.
    pub missed_before: u64,
}

impl TryFrom<pb::EpisodeSummary> for EpisodeSummary {
    type Error = Status;
    fn try_from(m: pb::EpisodeSummary) -> Result<Self, Status> {
        if m.task.is_empty() {
            return Err(Status::invalid_argument("EpisodeSummary: empty task name"));
        }
        if !m.episode_return.is_finite() {
            return Err(Status::invalid_argument(format!(
                "EpisodeSummary.episode_return is not finite ({})",
                m.episode_return
            )));
        }
        if m.guided_steps > m.length {
            return Err(Status::invalid_argument(format!(
                "EpisodeSummary: guided_steps {} exceeds length {}",
                m.guided_steps, m.length
            )));
        }
        Ok(Self {
            task: m.task,
            actor_id: m.actor_id,
            episode_index: m.episode_index,
            episode_return: m.episode_return,
            success: m.success,
            length: m.length,
            policy_version: m.policy_version,
            guided_steps: m.guided_steps,
            missed_before: m.missed_before,
        })
    }
}

impl From<EpisodeSummary> for pb::EpisodeSummary {
    fn from(d: EpisodeSummary) -> Self {
        Self {
            task: d.task,
            actor_id: d.actor_id,
            episode_index: d.episode_index,
            episode_return: d.episode_return,
            success: d.success,
            length: d.length,
            policy_version: d.policy_version,
            guided_steps: d.guided_steps,
            missed_before: d.missed_before,
        }
    }
}

/// One scalar metric sample (`losses/qf1_loss`, `charts/SPS`, ...).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metric {
    /// Metric name, cleanrl style (`losses/qf1_loss`, `charts/SPS`; never empty).
    pub name: String,
    /// The sample's value; may be non-finite (a diverging loss is recorded as it is).
    pub value: f64,
    /// Learner update count (or env steps, for actor-side metrics) the value belongs to.
    pub step: u64,
    /// Wall-clock time, nanoseconds since the Unix epoch.
    pub unix_time_nanos: u64,
}

impl TryFrom<pb::Metric> for Metric {
    type Error = Status;
    fn try_from(m: pb::Metric) -> Result<Self, Status> {
        if m.name.is_empty() {
            return Err(Status::invalid_argument("Metric: empty name"));
        }
        // Non-finite metric values are allowed: a diverging loss is worth recording as it is.
        Ok(Self {
            name: m.name,
            value: m.value,
            step: m.step,
            unix_time_nanos: m.unix_time_nanos,
        })
    }
}

impl From<Metric> for pb::Metric {
    fn from(d: Metric) -> Self {
        Self {
            name: d.name,
            value: d.value,
            step: d.step,
            unix_time_nanos: d.unix_time_nanos,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> TepSample {
        TepSample {
            task: "door-open".into(),
            trajectory_id: 7,
            step: 12,
            priority: 0.3,
            obs: [0.1; OBS_DIM],
            next_obs: [0.2; OBS_DIM],
            goal_obs: None,
            action: [0.5, -0.5, 1.0, -1.0],
            success: false,
            variation: None,
        }
    }

    #[test]
    fn tep_sample_round_trip_and_rejections() {
        let s = sample();
        assert_eq!(
            TepSample::try_from(pb::TepSample::from(s.clone())).unwrap(),
            s
        );
        assert_eq!(pb::TepSample::from(&s), pb::TepSample::from(s.clone()));
        let mut m = pb::TepSample::from(s);
        m.obs.pop();
        assert_eq!(
            TepSample::try_from(m.clone()).unwrap_err().message(),
            "TepSample.obs: expected 39 values, got 38"
        );
        m.obs.push(f32::NAN);
        assert_eq!(
            TepSample::try_from(m.clone()).unwrap_err().message(),
            "TepSample.obs[38] is not finite (NaN)"
        );
        m.obs[38] = 0.0;
        m.action[1] = 1.5;
        assert!(TepSample::try_from(m)
            .unwrap_err()
            .message()
            .contains("outside [-1, 1]"));
    }
}
