//! `--tep-dataset PATH` (repeatable): starts the TEP buffer from the selected transitions of
//! earlier runs (`runs/<id>/tep-dataset.mcap`, e.g. the five MT1-Ind runs for an MT10 run).
//! Samples of tasks this run does not train are skipped and counted; invalid ones were already
//! refused by the reader.
//!
//! Trajectory ids are only unique within one run (actor id and episode counter), and hindsight
//! goals are drawn within a trajectory, so each loaded trajectory gets a fresh id: the top bit
//! set, the file's index in bits 40..63 and a per-file sequence number below — distinct across
//! files and from the live selector's ids (actor ids below 32768 in the top 16 bits).

use std::collections::HashMap;
use std::path::Path;

use anyhow::Context;
use terl_transport::SelectedSample;
use terl_wire::TepSample;

use crate::planner::PlannerTrainer;

/// The id a trajectory of dataset file `file` gets when loaded (see the module docs).
pub(crate) fn loaded_trajectory_id(file: usize, sequence: u64) -> u64 {
    (1 << 63) | ((file as u64 & 0x7F_FFFF) << 40) | (sequence & ((1 << 40) - 1))
}

/// The shared-memory form of a dataset sample, if its task is one of `tasks`, with the
/// trajectory id `trajectory_id`.
fn to_selected(s: &TepSample, tasks: &[&str], trajectory_id: u64) -> Option<SelectedSample> {
    let task = tasks.iter().position(|t| *t == s.task)?;
    Some(SelectedSample {
        trajectory_id,
        obs: s.obs,
        next_obs: s.next_obs,
        action: s.action,
        reward: 0.0,
        priority: s.priority as f32,
        step_index: u16::try_from(s.step).ok()?,
        task: u16::try_from(task).ok()?,
        variation: s
            .variation
            .and_then(|v| u16::try_from(v).ok())
            .unwrap_or(u16::MAX),
        success: u8::from(s.success),
        reserved: 0,
    })
}

/// Loads the datasets at `paths` into the planner's buffer, in order. Each file must hold at
/// least one sample of this run's tasks.
pub(crate) fn load_all(
    paths: &[std::path::PathBuf],
    tasks: &[&str],
    planner: &mut PlannerTrainer,
) -> anyhow::Result<()> {
    let mut seen = Vec::new();
    for (file, path) in paths.iter().enumerate() {
        let canonical = std::fs::canonicalize(path).unwrap_or_else(|_| path.clone());
        anyhow::ensure!(
            !seen.contains(&canonical),
            "the TEP dataset {} is given twice (its samples would be loaded twice)",
            path.display()
        );
        seen.push(canonical);
        load_into(file, path, tasks, planner)?;
    }
    Ok(())
}

/// Loads the dataset at `path` (file number `file` of this start-up) into the planner's buffer.
pub(crate) fn load_into(
    file: usize,
    path: &Path,
    tasks: &[&str],
    planner: &mut PlannerTrainer,
) -> anyhow::Result<()> {
    let data = terl_telemetry::read_tep_dataset(path)
        .with_context(|| format!("cannot load the TEP dataset {}", path.display()))?;
    let mut ids: HashMap<u64, u64> = HashMap::new();
    let converted: Vec<SelectedSample> = data
        .samples
        .iter()
        .filter_map(|s| {
            let next = ids.len() as u64;
            let id = *ids
                .entry(s.trajectory_id)
                .or_insert_with(|| loaded_trajectory_id(file, next));
            to_selected(s, tasks, id)
        })
        .collect();
    if let Some(reason) = &data.truncation {
        tracing::warn!(
            path = %path.display(),
            kept = data.samples.len(),
            "the TEP dataset is read only in part: {reason}; using the samples before that point"
        );
    }
    let other_tasks = data.samples.len() - converted.len();
    let accepted = planner.ingest(&converted);
    tracing::info!(
        path = %path.display(),
        loaded = accepted,
        trajectories = ids.len(),
        other_tasks,
        invalid = data.rejected,
        truncated = data.truncated,
        "TEP buffer started from a dataset"
    );
    if let (true, Some(reason)) = (data.samples.is_empty(), &data.truncation) {
        anyhow::bail!(
            "the TEP dataset {} is damaged before its first sample: {reason}",
            path.display()
        );
    }
    anyhow::ensure!(
        accepted > 0 || data.samples.is_empty(),
        "the TEP dataset {} has no sample of this run's tasks",
        path.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_rl::TepConfig;
    use terl_telemetry::TepDatasetWriter;

    /// One trajectory of `steps` steps of `task`, with the id an earlier run gave it.
    fn write_dataset(path: &Path, task: &str, trajectory_id: u64, steps: u32) {
        let mut w = TepDatasetWriter::create(path).unwrap();
        for step in 0..steps {
            let v = step as f32 * 0.01;
            w.write(
                &TepSample {
                    task: task.into(),
                    trajectory_id,
                    step,
                    priority: 1.0,
                    obs: [v; terl_transport::OBS_DIM],
                    next_obs: [v + 0.01; terl_transport::OBS_DIM],
                    goal_obs: None,
                    action: [0.1; terl_transport::ACTION_DIM],
                    success: false,
                    variation: None,
                },
                u64::from(step),
            )
            .unwrap();
        }
        w.finish().unwrap();
    }

    #[test]
    fn several_datasets_with_the_same_trajectory_ids_all_load() {
        let dir = tempfile::tempdir().unwrap();
        // Two earlier runs (say two MT1-Ind tasks) whose actor 0 both wrote trajectory id 7.
        let a = dir.path().join("a.mcap");
        let b = dir.path().join("b.mcap");
        write_dataset(&a, "door-open-v3", 7, 30);
        write_dataset(&b, "window-open-v3", 7, 20);
        let tasks = ["door-open-v3", "window-open-v3"];
        let mut planner =
            PlannerTrainer::new(TepConfig::default(), Default::default(), tasks.len(), 1).unwrap();
        load_all(&[a.clone(), b], &tasks, &mut planner).unwrap();
        // Kept apart, nothing is merged away as a duplicate step of one trajectory (each is
        // held out for the planner check: the first trajectories of a task are).
        assert_eq!(planner.selected, 50);
        assert_eq!(planner.buffer_len() + planner.held_out_transitions(), 50);
        // The same file twice is refused.
        let mut planner =
            PlannerTrainer::new(TepConfig::default(), Default::default(), tasks.len(), 1).unwrap();
        let e = load_all(&[a.clone(), a.clone()], &tasks, &mut planner).unwrap_err();
        assert!(format!("{e:#}").contains("twice"), "{e:#}");
        // A file without any sample of the run's tasks is an error naming it.
        let mut planner =
            PlannerTrainer::new(TepConfig::default(), Default::default(), 1, 1).unwrap();
        let e = load_all(std::slice::from_ref(&a), &["reach-v3"], &mut planner).unwrap_err();
        assert!(format!("{e:#}").contains("a.mcap"), "{e:#}");
        // A file damaged inside its first chunk yields no sample: an error, not an empty start.
        let mut bytes = std::fs::read(&a).unwrap();
        let mid = bytes.len() / 2;
        for b in &mut bytes[mid..mid + 4] {
            *b ^= 0xff;
        }
        let c = dir.path().join("c.mcap");
        std::fs::write(&c, bytes).unwrap();
        let mut planner =
            PlannerTrainer::new(TepConfig::default(), Default::default(), tasks.len(), 1).unwrap();
        let e = load_all(&[c], &tasks, &mut planner).unwrap_err();
        assert!(format!("{e:#}").contains("damaged"), "{e:#}");
    }

    #[test]
    fn a_damaged_record_length_loads_the_samples_before_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tep-dataset.mcap");
        let mut w = TepDatasetWriter::create(&path).unwrap();
        let sample = |trajectory_id: u64, step: u32| TepSample {
            task: "door-open-v3".into(),
            trajectory_id,
            step,
            priority: 1.0,
            obs: [step as f32 * 0.01; terl_transport::OBS_DIM],
            next_obs: [0.5; terl_transport::OBS_DIM],
            goal_obs: None,
            action: [0.1; terl_transport::ACTION_DIM],
            success: false,
            variation: None,
        };
        // Two trajectories of 25 steps, flushed apart: one chunk each (after the schema chunk).
        for trajectory_id in [3, 4] {
            for step in 0..25 {
                w.write(&sample(trajectory_id, step), u64::from(step))
                    .unwrap();
            }
            w.flush().unwrap();
        }
        w.finish().unwrap();
        // Damage the length of the third top-level chunk (the second trajectory's) to 4.6 EB.
        let mut bytes = std::fs::read(&path).unwrap();
        let (mut at, mut chunks) = (8usize, 0);
        loop {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            chunks += usize::from(bytes[at] == 0x06);
            if chunks == 3 {
                break;
            }
            at += 9 + len;
        }
        bytes[at + 1..at + 9].copy_from_slice(&(4u64 << 60).to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();

        let tasks = ["door-open-v3"];
        let mut planner =
            PlannerTrainer::new(TepConfig::default(), Default::default(), tasks.len(), 1).unwrap();
        load_all(&[path], &tasks, &mut planner).unwrap();
        assert_eq!(planner.buffer_len() + planner.held_out_transitions(), 25);
    }

    #[test]
    fn loaded_ids_are_distinct_across_files_and_from_live_ids() {
        // The selector's live id of actor 31000's episode 5 (actor in the top 16 bits).
        let live = (31_000u64 << 48) | 5;
        let mut seen = std::collections::HashSet::new();
        for file in 0..3 {
            for seq in 0..100 {
                let id = loaded_trajectory_id(file, seq);
                assert!(seen.insert(id));
                assert!(id >> 63 == 1 && live >> 63 == 0);
            }
        }
    }
}
