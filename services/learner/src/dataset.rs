//! `--tep-dataset PATH`: starts the TEP buffer from the selected transitions of an earlier run
//! (`runs/<id>/tep-dataset.mcap`). Samples of tasks this run does not train are skipped and
//! counted; invalid ones were already refused by the reader.

use std::path::Path;

use anyhow::Context;
use terl_transport::SelectedSample;
use terl_wire::TepSample;

use crate::planner::PlannerTrainer;

/// The shared-memory form of a dataset sample, if its task is one of `tasks`.
fn to_selected(s: &TepSample, tasks: &[&str]) -> Option<SelectedSample> {
    let task = tasks.iter().position(|t| *t == s.task)?;
    Some(SelectedSample {
        trajectory_id: s.trajectory_id,
        obs: s.obs,
        next_obs: s.next_obs,
        action: s.action,
        reward: 0.0,
        priority: s.priority as f32,
        step_index: u16::try_from(s.step).ok()?,
        task: u16::try_from(task).ok()?,
        reserved: [0; 4],
    })
}

/// Loads the dataset at `path` into the planner's buffer.
pub(crate) fn load_into(
    path: &Path,
    tasks: &[&str],
    planner: &mut PlannerTrainer,
) -> anyhow::Result<()> {
    let data = terl_telemetry::read_tep_dataset(path)
        .with_context(|| format!("cannot load the TEP dataset {}", path.display()))?;
    let converted: Vec<SelectedSample> = data
        .samples
        .iter()
        .filter_map(|s| to_selected(s, tasks))
        .collect();
    let other_tasks = data.samples.len() - converted.len();
    let accepted = planner.ingest(&converted);
    tracing::info!(
        path = %path.display(),
        loaded = accepted,
        other_tasks,
        invalid = data.rejected,
        truncated = data.truncated,
        "TEP buffer started from a dataset"
    );
    anyhow::ensure!(
        accepted > 0 || data.samples.is_empty(),
        "the TEP dataset {} has no sample of this run's tasks",
        path.display()
    );
    Ok(())
}
