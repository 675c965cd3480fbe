//! Reading TEP datasets as trajectories, and planner files.

use std::collections::BTreeMap;

use std::path::{Path, PathBuf};
use terl_rl::guidance::MIN_VALIDATION_STEPS;

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
/// dropped), in file order, then in the order each trajectory first appears in its file (the
/// order a learner loading the file receives them). Trajectory ids are only unique within one
/// file, so file `f`'s ids get `f << 48` added. A file read only in part (cut, a chunk whose CRC
/// fails, a writer killed or still writing) is an error naming the damage, unless
/// `accept_partial` (then it is used up to the damage, with a warning). A file without any sample
/// (a run whose selection never started) is skipped with a warning; it is an error when no file
/// has one, and when a file is given twice.
pub fn read_trajectories(
    paths: &[std::path::PathBuf],
    accept_partial: bool,
) -> Result<Vec<Trajectory>> {
    let known = terl_sim::metaworld::task_names();
    let mut out = Vec::new();
    let mut empty = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for path in paths {
        let canonical = std::fs::canonicalize(path).unwrap_or_else(|_| path.clone());
        anyhow::ensure!(
            seen.insert(canonical),
            "the TEP dataset {} is given twice (its trajectories would count twice, and held-out \
             ones would train)",
            path.display()
        );
    }
    for (f, path) in paths.iter().enumerate() {
        let data = terl_telemetry::read_tep_dataset(path)
            .with_context(|| format!("cannot read the TEP dataset {}", path.display()))?;
        if let Some(reason) = &data.truncation {
            anyhow::ensure!(
                accept_partial,
                "the TEP dataset {} is damaged or incomplete: {reason} ({} samples readable \
                 before that point; --accept-partial uses them)",
                path.display(),
                data.samples.len()
            );
            tracing::warn!(path = %path.display(), "dataset read in part: {reason}");
        }
        if data.rejected > 0 {
            tracing::warn!(path = %path.display(), rejected = data.rejected, "invalid samples skipped");
        }
        let mut order: Vec<u64> = Vec::new();
        let mut by_id: std::collections::HashMap<u64, Vec<TepSample>> = Default::default();
        for s in data.samples {
            let entry = by_id.entry(s.trajectory_id).or_default();
            if entry.is_empty() {
                order.push(s.trajectory_id);
            }
            entry.push(s);
        }
        if order.is_empty() {
            empty.push(path.display().to_string());
            continue;
        }
        for id in order {
            let mut samples = by_id.remove(&id).unwrap_or_default();
            samples.sort_by_key(|s| s.step);
            samples.dedup_by_key(|s| s.step);
            anyhow::ensure!(
                known.contains(&samples[0].task.as_str()),
                "{}: trajectory {id} is of {:?}, not a Meta-World task",
                path.display(),
                samples[0].task
            );
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
/// with at least [`MIN_VALIDATION_STEPS`] samples, in read order ([`read_trajectories`]: file
/// order, then order of appearance), are held out, the rest train: the trajectories the
/// learner's gate holds out when it loads the same files.
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
        if *n < per_task && t.len() >= MIN_VALIDATION_STEPS {
            *n += 1;
            held.push(t);
        } else {
            train.push(t);
        }
    }
    (train, held)
}

/// Checks the output path of `flag` before any work is done: it must not be an existing
/// directory, device or pipe, nor one of `inputs` (the same file under any name), and its folder
/// is created if missing.
pub fn check_output(out: &Path, flag: &str, inputs: &[&Path]) -> Result<()> {
    if let Ok(meta) = std::fs::metadata(out) {
        anyhow::ensure!(
            meta.is_file(),
            "{flag} {} exists and is not a regular file (a directory, device or pipe); give the \
             path of a file to write",
            out.display()
        );
        let target = std::fs::canonicalize(out)?;
        for input in inputs {
            anyhow::ensure!(
                std::fs::canonicalize(input).ok().as_ref() != Some(&target),
                "{flag} {} is also an input ({}); writing it would destroy that input",
                out.display(),
                input.display()
            );
        }
    }
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("{flag} {}: cannot create its folder", out.display()))?;
    }
    Ok(())
}

/// `X` → `X.partial-<pid>`, where this process writes a file before renaming it to `X` (a
/// killed run leaves only that, clearly marked; two runs never share one).
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(format!(".partial-{}", std::process::id()));
    PathBuf::from(name)
}

/// Loads a planner file (`terl planner train --out`, or a learner's
/// `checkpoints/planner.safetensors`): its recorded config (`terl.tep_config`) and weights.
pub fn load_planner(path: &Path) -> Result<Tep<f32>> {
    let file = TensorFile::load(path)
        .with_context(|| format!("cannot read the planner file {}", path.display()))?;
    planner_from(&file, path)
}

/// The planner of a loaded planner file (`path` names it in errors): its recorded config is
/// checked (Meta-World's dimensions, network sizes within bounds) before any network is built.
pub fn planner_from(file: &TensorFile, path: &Path) -> Result<Tep<f32>> {
    let text = file.metadata.get("terl.tep_config").with_context(|| {
        format!(
            "{} has no terl.tep_config metadata: not a planner file of terl",
            path.display()
        )
    })?;
    let mut config = TepConfig::from_saved_toml(text)
        .with_context(|| format!("the config recorded in {}", path.display()))?;
    anyhow::ensure!(
        (config.obs_dim, config.act_dim) == (OBS_DIM, ACTION_DIM),
        "{} is a planner for observations of {} and actions of {} values; Meta-World's are {} \
         and {}",
        path.display(),
        config.obs_dim,
        config.act_dim,
        OBS_DIM,
        ACTION_DIM
    );
    config
        .validate()
        .with_context(|| format!("the config recorded in {}", path.display()))?;
    config.threads = 1;
    let mut tep: Tep<f32> = Tep::new(config)?;
    tep.import_planner(file)
        .with_context(|| format!("the weights of {}", path.display()))?;
    Ok(tep)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn traj_of(task: &str, id: u64, n: usize) -> Trajectory {
        Trajectory {
            task: task.into(),
            id,
            variation: None,
            steps: (0..n as u32).collect(),
            obs: vec![0.0; n * OBS_DIM],
            actions: vec![0.0; n * ACTION_DIM],
            next_obs: vec![0.0; n * OBS_DIM],
            success: vec![false; n],
        }
    }

    fn traj(task: &str, id: u64) -> Trajectory {
        traj_of(task, id, MIN_VALIDATION_STEPS)
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
        // A trajectory too short for the learner's check is not held out (it trains).
        let (train, held) = split_held_out(
            vec![traj_of("a", 1, MIN_VALIDATION_STEPS - 1), traj("a", 2)],
            1,
        );
        assert_eq!(ids(&held), [2]);
        assert_eq!(ids(&train), [1]);
    }
}
