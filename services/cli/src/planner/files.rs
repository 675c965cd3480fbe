//! Reading TEP datasets as trajectories, and planner files.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result};
use terl_nn::tensors::TensorFile;
use terl_rl::{Tep, TepConfig};
use terl_wire::{TepSample, ACTION_DIM, OBS_DIM};

/// One trajectory of a TEP dataset: its samples in step order.
#[derive(Clone, Debug)]
pub struct Trajectory {
    pub task: String,
    /// Id unique within the file it came from, with the file's index in the top bits (see
    /// [`read_trajectories`]).
    pub id: u64,
    pub variation: Option<u32>,
    pub steps: Vec<u32>,
    pub obs: Vec<f32>,
    pub actions: Vec<f32>,
    pub next_obs: Vec<f32>,
    pub success: Vec<bool>,
}

impl Trajectory {
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// Transitions up to and including the first success (all when it never succeeds).
    pub fn until_success(&self) -> usize {
        self.success
            .iter()
            .position(|&s| s)
            .map_or(self.len(), |i| i + 1)
    }

    /// Whether a transition reports success.
    pub fn succeeded(&self) -> bool {
        self.success.iter().any(|&s| s)
    }

    /// Whether the steps run 0, 1, 2, … without a hole (scripted datasets; selected data keeps
    /// only the top-ranked samples and may skip steps).
    pub fn contiguous(&self) -> bool {
        self.steps.iter().enumerate().all(|(i, &s)| s as usize == i)
    }

    pub fn next_obs_at(&self, i: usize) -> &[f32] {
        &self.next_obs[i * OBS_DIM..(i + 1) * OBS_DIM]
    }
}

/// Reads TEP datasets into trajectories (grouped by trajectory id, sorted by step, duplicates
/// dropped), in file order then id order. Trajectory ids are only unique within one file, so
/// file `f`'s ids get `f << 48` added. A truncated file is used up to its damage, with a warning.
/// A file without any sample (a run whose selection never started) is skipped with a warning;
/// it is an error when no file has one.
pub fn read_trajectories(paths: &[std::path::PathBuf]) -> Result<Vec<Trajectory>> {
    let mut out = Vec::new();
    let mut empty = Vec::new();
    for (f, path) in paths.iter().enumerate() {
        let data = terl_telemetry::read_tep_dataset(path)
            .with_context(|| format!("cannot read the TEP dataset {}", path.display()))?;
        if let Some(reason) = &data.truncation {
            tracing::warn!(path = %path.display(), "dataset read in part: {reason}");
        }
        if data.rejected > 0 {
            tracing::warn!(path = %path.display(), rejected = data.rejected, "invalid samples skipped");
        }
        let mut by_id: BTreeMap<u64, Vec<TepSample>> = BTreeMap::new();
        for s in data.samples {
            by_id.entry(s.trajectory_id).or_default().push(s);
        }
        if by_id.is_empty() {
            empty.push(path.display().to_string());
            continue;
        }
        for (id, mut samples) in by_id {
            samples.sort_by_key(|s| s.step);
            samples.dedup_by_key(|s| s.step);
            let mut t = Trajectory {
                task: samples[0].task.clone(),
                id: ((f as u64) << 48) | (id & ((1 << 48) - 1)),
                variation: samples[0].variation,
                steps: Vec::with_capacity(samples.len()),
                obs: Vec::with_capacity(samples.len() * OBS_DIM),
                actions: Vec::with_capacity(samples.len() * ACTION_DIM),
                next_obs: Vec::with_capacity(samples.len() * OBS_DIM),
                success: Vec::with_capacity(samples.len()),
            };
            for s in &samples {
                anyhow::ensure!(
                    s.task == t.task,
                    "{}: trajectory {id} mixes tasks {} and {}",
                    path.display(),
                    t.task,
                    s.task
                );
                t.steps.push(s.step);
                t.obs.extend_from_slice(&s.obs);
                t.actions.extend_from_slice(&s.action);
                t.next_obs.extend_from_slice(&s.next_obs);
                t.success.push(s.success);
            }
            out.push(t);
        }
    }
    match (out.is_empty(), empty.as_slice()) {
        (true, [one]) => anyhow::bail!("the TEP dataset {one} holds no sample"),
        (true, _) => anyhow::bail!("the TEP datasets {} hold no sample", empty.join(", ")),
        (false, _) => {
            for path in &empty {
                eprintln!("[planner] skipping the TEP dataset {path}: it holds no sample");
            }
        }
    }
    Ok(out)
}

/// Splits trajectories into (training, held out): the first `per_task` trajectories of each task
/// in read order ([`read_trajectories`]: file order, then id order) are held out, the rest train.
/// `terl planner train --hold-out-trajectories K` trains on the first part and `terl planner eval
/// --hold-out-trajectories K` scores the second, so one PTR-selected dataset of a run serves
/// both without overlap (the learner's gate holds out a task's first selected trajectories the
/// same way).
pub fn split_held_out(
    trajectories: Vec<Trajectory>,
    per_task: usize,
) -> (Vec<Trajectory>, Vec<Trajectory>) {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let (mut train, mut held) = (Vec::new(), Vec::new());
    for t in trajectories {
        let n = seen.entry(t.task.clone()).or_default();
        if *n < per_task {
            *n += 1;
            held.push(t);
        } else {
            train.push(t);
        }
    }
    (train, held)
}

/// Loads a planner file (`terl planner train --out`, or a learner's
/// `checkpoints/planner.safetensors`): its recorded config (`terl.tep_config`) and weights.
pub fn load_planner(path: &Path) -> Result<Tep<f32>> {
    let file = TensorFile::load(path)
        .with_context(|| format!("cannot read the planner file {}", path.display()))?;
    let text = file.metadata.get("terl.tep_config").with_context(|| {
        format!(
            "{} has no terl.tep_config metadata: not a planner file of terl",
            path.display()
        )
    })?;
    let mut config = TepConfig::from_saved_toml(text)
        .with_context(|| format!("the config recorded in {}", path.display()))?;
    config.threads = 1;
    let mut tep: Tep<f32> = Tep::new(config)?;
    tep.import_planner(&file)
        .with_context(|| format!("the weights of {}", path.display()))?;
    Ok(tep)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn traj(task: &str, id: u64) -> Trajectory {
        Trajectory {
            task: task.into(),
            id,
            variation: None,
            steps: vec![0],
            obs: vec![0.0; OBS_DIM],
            actions: vec![0.0; ACTION_DIM],
            next_obs: vec![0.0; OBS_DIM],
            success: vec![false],
        }
    }

    #[test]
    fn the_first_trajectories_of_each_task_are_held_out_and_the_rest_train() {
        let all = vec![
            traj("a", 1),
            traj("b", 2),
            traj("a", 3),
            traj("a", 4),
            traj("b", 5),
        ];
        let (train, held) = split_held_out(all.clone(), 2);
        let ids = |v: &[Trajectory]| v.iter().map(|t| t.id).collect::<Vec<_>>();
        assert_eq!(ids(&held), [1, 2, 3, 5]);
        assert_eq!(ids(&train), [4]);
        let (train, held) = split_held_out(all, 0);
        assert!(held.is_empty());
        assert_eq!(train.len(), 5);
    }
}
