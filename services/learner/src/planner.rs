//! The learner's TEP side (`algorithm = "terl"`): the TEP buffer fed by the selector's selected
//! samples (and optionally a dataset from an earlier run), TEP updates interleaved with SAC
//! updates, planner weights for the weight stream, planner checkpoints.
//!
//! **The guidance gate.** The first `[guidance] validation_trajectories` selected trajectories
//! of each task (at least [`MIN_VALIDATION_STEPS`] transitions) are held out of the TEP buffer.
//! Every `validate_every_updates` TEP updates F is scored on them ([`terl_rl::planner_eval`]:
//! Spearman ρ between F and the step gap); a task whose ρ reaches `min_spearman` is validated
//! (latched) and from then on the actors guide it. The gate goes out with the planner weights
//! (`tep_gate.validated`, one 0/1 per task), with the goal library of the final-state goal source
//! (`tep_goals.tasks`, `tep_goals.states`: the state after the first success of the [`GOALS_PER_TASK`] most recent
//! selected trajectories per task). A planner given with `[tep] init_planner` (trained offline,
//! `terl planner train`) is checked on the held-out trajectories of the datasets loaded at start,
//! so its tasks are guided from the first step.

use std::collections::BTreeMap;
#[cfg(test)]
use std::path::Path;

use anyhow::Context;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
#[cfg(test)]
use terl_nn::tensors::save_file;
use terl_nn::tensors::{Tensor, TensorFile};
use terl_rl::{names, SacError, Tep, TepBatch, TepBuffer, TepConfig};
use terl_transport::{SelectedBatch, SelectedSample, ACTION_DIM, OBS_DIM};
use terl_wire::{Weights, WeightsKind};

use crate::checkpoint::{PlannerState, RngState};

/// TEP updates per trainer round at most (one update at the paper's size takes a while on a
/// CPU; transitions and status must not wait for a long catch-up).
const MAX_TEP_UPDATES_PER_ROUND: u64 = 2;

/// Goal states kept per task for the actors' final-state goals.
pub(crate) const GOALS_PER_TASK: usize = terl_rl::guidance::GOAL_LIBRARY_PER_TASK;

/// Shortest selected trajectory (transitions) held out for the planner check.
pub(crate) use terl_rl::guidance::MIN_VALIDATION_STEPS;

/// Pairs per held-out trajectory in the planner check.
const VALIDATION_PAIRS: usize = 200;

/// One held-out trajectory segment.
#[derive(Debug, Clone)]
struct HeldOut {
    steps: Vec<u32>,
    obs: Vec<f32>,
    actions: Vec<f32>,
    next_obs: Vec<f32>,
}

/// Running sums of the losses over the current reporting window.
#[derive(Debug, Default, Clone, Copy)]
struct LossWindow {
    f: f64,
    an: f64,
    target: f64,
    distance: f64,
    step: f64,
    goal: f64,
    symmetry: f64,
    bc: f64,
    gap: f64,
    n: u64,
}

pub(crate) struct PlannerTrainer {
    tep: Tep<f32>,
    buffer: TepBuffer,
    batch: TepBatch,
    rng: ChaCha8Rng,
    num_tasks: usize,
    /// SAC updates done when the buffer first held a full minibatch: the interleaving ratio
    /// counts from there, so TEP does not "catch up" on SAC updates it could not follow.
    sac_offset: Option<u64>,
    /// Selected transitions accepted into the buffer.
    pub(crate) selected: u64,
    /// Selected transitions refused (unknown task, non-finite values, action outside [−1, 1]).
    pub(crate) rejected: u64,
    /// Selected transitions after their trajectory's first success, left out of the buffer (in
    /// this process; not checkpointed): a Meta-World episode runs on after success with the
    /// arm at the goal, so those states all sit at the goal while their step gaps run to
    /// hundreds, which F cannot fit (held-out ρ stayed at 0.14–0.59 with them, MT1-Ind 500k).
    /// The offline datasets end at the first success for the same reason.
    pub(crate) after_success: u64,
    window: LossWindow,
    /// Mean losses of the last completed window (what status shows).
    pub(crate) shown_f_loss: f64,
    pub(crate) shown_an_loss: f64,
    /// Mean bootstrapped target `1 + F̃(..)` of the last completed window (≥ 1).
    pub(crate) shown_target_mean: f64,
    /// Mean predicted distance `F(s_t, s', a_t)` to the hindsight goal, last window (≥ 0).
    pub(crate) shown_goal_distance_mean: f64,
    pub(crate) failed_updates: u64,
    published_version: u64,
    /// The gate's settings (`[guidance]`).
    guidance: terl_rl::guidance::GuidanceConfig,
    held_out: Vec<Vec<HeldOut>>,
    held_out_ids: std::collections::HashSet<u64>,
    /// Per task, the last states of recent selected trajectories (oldest first).
    goals: Vec<std::collections::VecDeque<[f32; OBS_DIM]>>,
    /// Per task, ρ of the last check (NaN before one).
    pub(crate) spearman: Vec<f64>,
    /// Per task, TEP update count at which it was validated.
    pub(crate) validated_at: Vec<Option<u64>>,
    /// Per task, transitions in the TEP buffer (pushed, before overwriting).
    pub(crate) task_transitions: Vec<u64>,
    last_check: Option<u64>,
    /// Added to the update count to version the weights: 1 for a pretrained planner, so its
    /// weights go out before the first update.
    version_offset: u64,
    /// The gate changed since the last publication (publish even without an update).
    gate_changed: bool,
    /// Last window's means of F's three loss terms, AN's behaviour-cloning term, the gap.
    pub(crate) shown_step_loss: f64,
    pub(crate) shown_goal_loss: f64,
    pub(crate) shown_symmetry_loss: f64,
    pub(crate) shown_an_bc_loss: f64,
    pub(crate) shown_gap_mean: f64,
}

fn sample_ok(s: &SelectedSample, num_tasks: usize) -> bool {
    usize::from(s.task) < num_tasks
        && s.obs.iter().chain(&s.next_obs).all(|v| v.is_finite())
        && s.action.iter().all(|a| a.is_finite() && a.abs() <= 1.0)
}

impl PlannerTrainer {
    pub(crate) fn new(
        mut config: TepConfig,
        guidance: terl_rl::guidance::GuidanceConfig,
        num_tasks: usize,
        seed: u64,
    ) -> anyhow::Result<Self> {
        config.obs_dim = OBS_DIM;
        config.act_dim = ACTION_DIM;
        config.seed = seed;
        let mut tep = Tep::new(config.clone())?;
        let mut version_offset = 0;
        if let Some(path) = &config.init_planner {
            load_pretrained(&mut tep, std::path::Path::new(path))?;
            version_offset = 1;
        }
        Ok(Self {
            buffer: TepBuffer::new(config.buffer_capacity, OBS_DIM, ACTION_DIM),
            batch: TepBatch::with_capacity(config.batch_size, OBS_DIM, ACTION_DIM),
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x7e9_5a3d),
            tep,
            num_tasks,
            sac_offset: None,
            selected: 0,
            rejected: 0,
            after_success: 0,
            window: LossWindow::default(),
            shown_f_loss: 0.0,
            shown_an_loss: 0.0,
            shown_target_mean: 0.0,
            shown_goal_distance_mean: 0.0,
            failed_updates: 0,
            published_version: 0,
            guidance,
            held_out: vec![Vec::new(); num_tasks],
            held_out_ids: Default::default(),
            goals: vec![Default::default(); num_tasks],
            spearman: vec![f64::NAN; num_tasks],
            validated_at: vec![None; num_tasks],
            task_transitions: vec![0; num_tasks],
            last_check: None,
            version_offset,
            gate_changed: false,
            shown_step_loss: 0.0,
            shown_goal_loss: 0.0,
            shown_symmetry_loss: 0.0,
            shown_an_bc_loss: 0.0,
            shown_gap_mean: 0.0,
        })
    }

    /// Transitions held out of the buffer for the planner check.
    #[cfg(test)]
    pub(crate) fn held_out_transitions(&self) -> usize {
        self.held_out.iter().flatten().map(|h| h.steps.len()).sum()
    }

    /// The planner part of the status (`tasks`: the run's task names, in order).
    pub(crate) fn status(&self, tasks: &[&str]) -> terl_wire::PlannerStatus {
        terl_wire::PlannerStatus {
            step_loss: self.shown_step_loss,
            goal_loss: self.shown_goal_loss,
            symmetry_loss: self.shown_symmetry_loss,
            an_bc_loss: self.shown_an_bc_loss,
            gap_mean: self.shown_gap_mean,
            tasks: tasks
                .iter()
                .enumerate()
                .map(|(k, name)| terl_wire::PlannerTask {
                    task: name.to_string(),
                    spearman: self.spearman[k].is_finite().then_some(self.spearman[k]),
                    validated: self.validated_at[k].is_some(),
                    validated_at_tep_update: self.validated_at[k].unwrap_or(0),
                    tep_transitions: self.task_transitions[k],
                    held_out_trajectories: self.held_out[k].len() as u64,
                    held_out_transitions: self.held_out[k]
                        .iter()
                        .map(|h| h.steps.len() as u64)
                        .sum(),
                })
                .collect(),
        }
    }

    /// Scores F on each task's held-out trajectories and validates the tasks that pass (see
    /// the module docs). Runs at most once per `validate_every_updates` TEP updates unless
    /// `force`.
    pub(crate) fn check(&mut self, force: bool) {
        let updates = self.tep.updates();
        if !force
            && self
                .last_check
                .is_some_and(|u| updates.saturating_sub(u) < self.guidance.validate_every_updates)
        {
            return;
        }
        if self.held_out.iter().all(Vec::is_empty) {
            return;
        }
        self.last_check = Some(updates);
        let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_ca11);
        let mut pairs = terl_rl::planner_eval::PairSet::new(OBS_DIM, ACTION_DIM);
        for (task, trajectories) in self.held_out.iter().enumerate() {
            for h in trajectories {
                pairs.add_segment(
                    task,
                    &h.steps,
                    &h.obs,
                    &h.actions,
                    &h.next_obs,
                    VALIDATION_PAIRS,
                    &mut rng,
                );
            }
        }
        let pred =
            terl_rl::planner_eval::predict_gaps(&self.tep, &pairs, terl_nn::par_for_threads(1));
        let rho = terl_rl::planner_eval::spearman_per_task(&pred, &pairs, self.num_tasks);
        for (task, &r) in rho.iter().enumerate() {
            self.spearman[task] = r;
            if self.validated_at[task].is_none() && r >= self.guidance.min_spearman {
                self.validated_at[task] = Some(updates);
                self.gate_changed = true;
                tracing::info!(
                    task,
                    spearman = format!("{r:.3}"),
                    tep_updates = updates,
                    "planner validated for the task: guidance starts"
                );
            }
        }
    }

    /// Whether every task is validated and has at least `samples_per_task` transitions in the
    /// TEP buffer (`cluster.stop_at_planner_samples_per_task`).
    pub(crate) fn ready(&self, samples_per_task: u64) -> bool {
        self.validated_at.iter().all(Option::is_some)
            && self.task_transitions.iter().all(|&n| n >= samples_per_task)
    }

    /// The gate and goal library as tensors of the planner weights message.
    fn gate_tensors(&self) -> Vec<Tensor> {
        let validated: Vec<f32> = self
            .validated_at
            .iter()
            .map(|v| if v.is_some() { 1.0 } else { 0.0 })
            .collect();
        let mut tasks = Vec::new();
        let mut states = Vec::new();
        for (task, g) in self.goals.iter().enumerate() {
            for s in g {
                tasks.push(task as f32);
                states.extend_from_slice(s);
            }
        }
        let n = tasks.len();
        vec![
            Tensor::from_values(names::TEP_GATE, vec![self.num_tasks], &validated),
            Tensor::from_values(names::TEP_GOAL_TASKS, vec![n], &tasks),
            Tensor::from_values(names::TEP_GOAL_STATES, vec![n, OBS_DIM], &states),
        ]
    }

    pub(crate) fn updates(&self) -> u64 {
        self.tep.updates()
    }

    pub(crate) fn buffer_len(&self) -> usize {
        self.buffer.len()
    }

    pub(crate) fn buffer_capacity(&self) -> usize {
        self.buffer.capacity()
    }

    /// Adds samples to the TEP buffer, one segment per trajectory (steps ascending, duplicates
    /// dropped), so hindsight goals come from later states of the same trajectory. Invalid
    /// samples are counted and skipped. Returns the samples accepted.
    pub(crate) fn ingest(&mut self, samples: &[SelectedSample]) -> u64 {
        let mut order: Vec<&SelectedSample> = Vec::with_capacity(samples.len());
        for s in samples {
            if sample_ok(s, self.num_tasks) {
                order.push(s);
            } else {
                self.rejected += 1;
            }
        }
        order.sort_by_key(|s| (s.trajectory_id, s.step_index));
        order.dedup_by_key(|s| (s.trajectory_id, s.step_index));
        let mut accepted = 0;
        for seg in order.chunk_by(|a, b| a.trajectory_id == b.trajectory_id) {
            // Up to and including the first success-flagged transition (its next state is the
            // success state); the rest of the trajectory stays out.
            let end = seg
                .iter()
                .position(|s| s.succeeded())
                .map_or(seg.len(), |i| i + 1);
            self.after_success += (seg.len() - end) as u64;
            let selected_len = seg.len();
            let seg = &seg[..end];
            let steps: Vec<u32> = seg.iter().map(|s| u32::from(s.step_index)).collect();
            let obs: Vec<f32> = seg.iter().flat_map(|s| s.obs).collect();
            let next_obs: Vec<f32> = seg.iter().flat_map(|s| s.next_obs).collect();
            let actions: Vec<f32> = seg.iter().flat_map(|s| s.action).collect();
            let task = usize::from(seg[0].task);
            let id = seg[0].trajectory_id;
            // The goal library holds real success states: the state after a selected
            // trajectory's first success-flagged sample. A trajectory without one adds nothing.
            if selected_len >= MIN_VALIDATION_STEPS {
                if let Some(s) = seg.iter().find(|s| s.succeeded()) {
                    let g = &mut self.goals[task];
                    if g.len() == GOALS_PER_TASK {
                        g.pop_front();
                    }
                    g.push_back(s.next_obs);
                }
            }
            let hold = self.held_out_ids.contains(&id)
                || (self.held_out[task].len() < self.guidance.validation_trajectories
                    && selected_len >= MIN_VALIDATION_STEPS);
            if hold {
                self.held_out_ids.insert(id);
                self.held_out[task].push(HeldOut {
                    steps,
                    obs,
                    actions,
                    next_obs,
                });
                accepted += seg.len() as u64;
                continue;
            }
            self.task_transitions[task] += seg.len() as u64;
            match self.buffer.push_segment(
                u32::from(seg[0].task),
                seg[0].trajectory_id,
                &steps,
                &obs,
                &actions,
                &next_obs,
            ) {
                Ok(()) => accepted += seg.len() as u64,
                Err(e) => {
                    self.rejected += seg.len() as u64;
                    tracing::warn!("selected segment refused: {e}");
                }
            }
        }
        self.selected += accepted;
        accepted
    }

    /// [`PlannerTrainer::ingest`] for one shared-memory batch.
    pub(crate) fn ingest_batch(&mut self, batch: &SelectedBatch) -> u64 {
        self.ingest(batch.as_slice())
    }

    /// Runs the TEP updates due after `sac_updates` SAC updates (at most a few per call).
    /// Returns how many ran. A non-finite loss or gradient skips that update (weights
    /// unchanged, counted); other errors are fatal.
    pub(crate) fn train(&mut self, sac_updates: u64) -> anyhow::Result<u64> {
        let bs = self.tep.config().batch_size;
        if self.buffer.len() < bs {
            return Ok(0);
        }
        let offset = *self.sac_offset.get_or_insert(sac_updates);
        let due = self
            .tep
            .config()
            .updates_due(sac_updates - offset, self.tep.updates())
            .min(MAX_TEP_UPDATES_PER_ROUND);
        let mut ran = 0;
        for _ in 0..due {
            let sampling = self.tep.config().goal_sampling();
            if let Err(e) =
                self.buffer
                    .sample_into_with(bs, &mut self.rng, &mut self.batch, sampling)
            {
                // Only trajectories of one selected step each: wait for more data.
                tracing::debug!("no TEP minibatch yet: {e}");
                break;
            }
            match self.tep.update(&self.batch) {
                Ok(stats) => {
                    self.window.f += stats.f_loss;
                    self.window.an += stats.an_loss;
                    self.window.target += stats.target_mean;
                    self.window.distance += stats.goal_distance_mean;
                    self.window.step += stats.step_loss;
                    self.window.goal += stats.goal_loss;
                    self.window.symmetry += stats.symmetry_loss;
                    self.window.bc += stats.an_bc_loss;
                    self.window.gap += stats.gap_mean;
                    self.window.n += 1;
                    ran += 1;
                }
                Err(
                    e @ (SacError::NonFiniteBatch { .. }
                    | SacError::NonFiniteLoss { .. }
                    | SacError::NonFiniteGradient { .. }),
                ) => {
                    self.failed_updates += 1;
                    tracing::warn!("TEP update skipped: {e}");
                }
                Err(e) => return Err(e.into()),
            }
        }
        if ran > 0 {
            self.check(false);
        }
        Ok(ran)
    }

    /// Closes the loss window (called with the learner's rate window).
    pub(crate) fn roll_window(&mut self) {
        if self.window.n > 0 {
            self.shown_f_loss = self.window.f / self.window.n as f64;
            self.shown_an_loss = self.window.an / self.window.n as f64;
            self.shown_target_mean = self.window.target / self.window.n as f64;
            self.shown_goal_distance_mean = self.window.distance / self.window.n as f64;
            let n = self.window.n as f64;
            self.shown_step_loss = self.window.step / n;
            self.shown_goal_loss = self.window.goal / n;
            self.shown_symmetry_loss = self.window.symmetry / n;
            self.shown_an_bc_loss = self.window.bc / n;
            self.shown_gap_mean = self.window.gap / n;
        }
        self.window = LossWindow::default();
    }

    /// Planner weights to publish, if TEP trained since the last publication.
    pub(crate) fn weights_to_publish(&mut self) -> anyhow::Result<Option<Weights>> {
        let mut version = self.tep.updates() + self.version_offset;
        if version == 0 || (version <= self.published_version && !self.gate_changed) {
            return Ok(None);
        }
        // A gate change without an update still goes out, under a new version.
        version = version.max(self.published_version + 1);
        let mut tensors = self.tep.planner_tensors();
        tensors.extend(self.gate_tensors());
        let weights = crate::to_weights(WeightsKind::Planner, version, version, tensors)?;
        self.published_version = version;
        self.gate_changed = false;
        Ok(Some(weights))
    }

    pub(crate) fn published_version(&self) -> u64 {
        self.published_version
    }

    /// F, AN and both targets with the config and update count in the metadata: the content
    /// of `checkpoints/planner.safetensors` (for tools; resuming uses
    /// [`PlannerTrainer::checkpoint_tensors`] inside the learner checkpoint).
    pub(crate) fn tool_file(&self) -> anyhow::Result<(Vec<Tensor>, BTreeMap<String, String>)> {
        let mut tensors = Vec::new();
        self.tep.f_net().export(names::TEP_F, &mut tensors);
        self.tep.an_net().export(names::TEP_AN, &mut tensors);
        self.tep
            .f_target_net()
            .export(names::TEP_F_TARGET, &mut tensors);
        self.tep
            .an_target_net()
            .export(names::TEP_AN_TARGET, &mut tensors);
        let mut meta = BTreeMap::new();
        meta.insert("format".to_string(), "pt".to_string());
        meta.insert(
            "terl.tep_config".to_string(),
            toml::to_string(self.tep.config())?,
        );
        meta.insert(
            "terl.tep_updates".to_string(),
            self.tep.updates().to_string(),
        );
        Ok((tensors, meta))
    }

    /// Writes [`PlannerTrainer::tool_file`] to `path` (atomically and durably).
    #[cfg(test)]
    pub(crate) fn save(&self, path: &Path) -> anyhow::Result<()> {
        let (tensors, meta) = self.tool_file()?;
        save_file(path, &tensors, &meta)?;
        Ok(())
    }

    /// Everything of the planner a resumed run needs in tensors: networks, targets,
    /// optimisers, counters ([`terl_rl::Tep::checkpoint_tensors`]).
    pub(crate) fn checkpoint_tensors(&self) -> Vec<Tensor> {
        self.tep.checkpoint_tensors()
    }

    /// The rest of the planner trainer's state (sampler, counters, interleaving offset). The TEP
    /// buffer is not in it: a resumed learner reloads it from the run's dataset files.
    pub(crate) fn state(&self) -> PlannerState {
        PlannerState {
            sac_offset: self.sac_offset,
            selected: self.selected,
            rejected: self.rejected,
            failed_updates: self.failed_updates,
            published_version: self.published_version,
            rng: RngState::of(&self.rng),
        }
    }

    /// Restores what [`PlannerTrainer::checkpoint_tensors`] and [`PlannerTrainer::state`]
    /// saved. On error nothing is changed. The published version starts again from 0, so the
    /// restored planner goes out with the next publication.
    pub(crate) fn restore(
        &mut self,
        file: &TensorFile,
        state: &PlannerState,
    ) -> anyhow::Result<()> {
        let rng = state.rng.restore()?;
        self.tep
            .restore_checkpoint(file)
            .context("the checkpoint's planner does not fit this run's [tep] networks")?;
        self.rng = rng;
        self.sac_offset = state.sac_offset;
        self.selected = state.selected;
        self.rejected = state.rejected;
        self.failed_updates = state.failed_updates;
        self.published_version = 0;
        Ok(())
    }
}

/// Loads a planner file (`terl planner train --out`) into `tep`: its recorded networks must be
/// this run's `[tep]` networks with the same output scale (what F's numbers mean).
fn load_pretrained(tep: &mut Tep<f32>, path: &std::path::Path) -> anyhow::Result<()> {
    let file = TensorFile::load(path).with_context(|| {
        format!(
            "cannot read the planner file {} ([tep] init_planner)",
            path.display()
        )
    })?;
    if let Some(text) = file.metadata.get("terl.tep_config") {
        let saved = TepConfig::from_saved_toml(text)
            .with_context(|| format!("the config recorded in {}", path.display()))?;
        let c = tep.config();
        anyhow::ensure!(
            saved.f_hidden == c.f_hidden
                && saved.an_hidden == c.an_hidden
                && saved.f_output_scale == c.f_output_scale,
            "the planner {} has F {:?}, AN {:?}, output scale {}; this run's [tep] has {:?}, \
             {:?}, {}: set them to the planner's",
            path.display(),
            saved.f_hidden,
            saved.an_hidden,
            saved.f_output_scale,
            c.f_hidden,
            c.an_hidden,
            c.f_output_scale
        );
    }
    tep.import_planner(&file).with_context(|| {
        format!(
            "the weights of {} do not fit this run's [tep]",
            path.display()
        )
    })?;
    tracing::info!(path = %path.display(), "planner started from a planner file");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(trajectory: u64, step: u16, task: u16) -> SelectedSample {
        let mut s = SelectedSample::ZERO;
        s.trajectory_id = trajectory;
        s.step_index = step;
        s.task = task;
        s.obs[0] = f32::from(step);
        s.next_obs[0] = f32::from(step) + 1.0;
        s.action = [0.5, -0.5, 0.0, 1.0];
        s
    }

    fn small() -> TepConfig {
        TepConfig {
            f_hidden: vec![16],
            an_hidden: vec![16],
            batch_size: 4,
            buffer_capacity: 64,
            ..TepConfig::default()
        }
    }

    #[test]
    fn bad_samples_are_counted_and_segments_are_grouped() {
        let mut p = PlannerTrainer::new(small(), Default::default(), 2, 1).unwrap();
        let mut bad_task = sample(1, 0, 5);
        bad_task.obs[3] = 0.0;
        let mut nan = sample(1, 1, 0);
        nan.next_obs[2] = f32::NAN;
        let mut wide = sample(2, 1, 0);
        wide.action[1] = 1.5;
        // Out of order and duplicated: grouped per trajectory, sorted, deduplicated.
        let batch = [
            sample(7, 4, 1),
            sample(3, 2, 0),
            bad_task,
            sample(7, 1, 1),
            nan,
            sample(3, 0, 0),
            sample(7, 4, 1),
            wide,
        ];
        assert_eq!(p.ingest(&batch), 4);
        assert_eq!(p.rejected, 3);
        assert_eq!(p.buffer_len(), 4);
        let metas: Vec<_> = (0..4).map(|i| p.buffer.meta(i)).collect();
        assert_eq!(metas, vec![(0, 3, 0), (0, 3, 2), (1, 7, 1), (1, 7, 4)]);
    }

    /// A selected trajectory enters the buffer up to and including its first success-flagged
    /// transition; the hovering after it is counted and left out, and the success state is
    /// still the goal library's.
    #[test]
    fn transitions_after_the_first_success_stay_out_of_the_buffer() {
        let guidance = terl_rl::guidance::GuidanceConfig {
            validation_trajectories: 0,
            ..Default::default()
        };
        let mut p = PlannerTrainer::new(small(), guidance, 1, 1).unwrap();
        // Success from step 3 on (the selector flags every step from the first success).
        let traj: Vec<SelectedSample> = (0..40)
            .map(|k| {
                let mut s = sample(5, k, 0);
                s.success = u8::from(k >= 3);
                s
            })
            .collect();
        assert_eq!(p.ingest(&traj), 4);
        assert_eq!(p.after_success, 36);
        assert_eq!(p.buffer_len(), 4);
        let steps: Vec<_> = (0..4).map(|i| p.buffer.meta(i).2).collect();
        assert_eq!(steps, vec![0, 1, 2, 3]);
        assert_eq!(
            p.goals[0].back().map(|g| g[0]),
            Some(4.0),
            "the state after step 3"
        );
        // A trajectory that never succeeds goes in whole.
        let failed: Vec<SelectedSample> = (0..40).map(|k| sample(6, k, 0)).collect();
        assert_eq!(p.ingest(&failed), 40);
        assert_eq!(p.after_success, 36);
    }

    #[test]
    fn trains_once_a_minibatch_is_there_and_publishes_new_versions_only() {
        let mut p = PlannerTrainer::new(small(), Default::default(), 1, 1).unwrap();
        assert_eq!(p.train(10).unwrap(), 0, "empty buffer: nothing to do");
        let traj: Vec<SelectedSample> = (0..8).map(|k| sample(1, k, 0)).collect();
        p.ingest(&traj);
        // The ratio counts from the first trainable moment: SAC update 10 here.
        assert_eq!(p.train(10).unwrap(), 0);
        assert_eq!(p.train(11).unwrap(), 1);
        assert_eq!(p.train(20).unwrap(), MAX_TEP_UPDATES_PER_ROUND);
        let w = p.weights_to_publish().unwrap().expect("new version");
        assert_eq!(w.version(), p.updates());
        assert!(p.weights_to_publish().unwrap().is_none());
        p.roll_window();
        assert!(p.shown_f_loss > 0.0 && p.shown_f_loss.is_finite());
        assert!(p.shown_target_mean >= 1.0, "{}", p.shown_target_mean);
        assert!(p.shown_goal_distance_mean >= 0.0);
        let dir = std::env::temp_dir().join(format!("terl-planner-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("planner.safetensors");
        p.save(&path).unwrap();
        let file = terl_nn::tensors::TensorFile::load(&path).unwrap();
        let f0 = file.get("tep_f.0.weight", &[16, 82]).unwrap();
        assert_eq!(f0.values::<f32>().unwrap().len(), 16 * 82);
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// The first trajectories of each task are held out and scored; a task passes at its
    /// threshold, and the gate and the goal library go out with the weights.
    #[test]
    fn held_out_trajectories_gate_tasks_and_go_out_with_the_weights() {
        // Trajectory 1 succeeds from step 5 on; the others never do.
        let traj = |id: u64, task: u16| -> Vec<SelectedSample> {
            (0..12)
                .map(|k| {
                    let mut s = sample(id, k, task);
                    s.success = u8::from(id == 1 && k >= 5);
                    s
                })
                .collect()
        };
        for (threshold, want) in [(-1.0, true), (1.0, false)] {
            let guidance = terl_rl::guidance::GuidanceConfig {
                min_spearman: threshold,
                validation_trajectories: 1,
                ..Default::default()
            };
            let mut p = PlannerTrainer::new(small(), guidance, 2, 1).unwrap();
            p.ingest(&traj(1, 0));
            p.ingest(&traj(2, 0));
            assert_eq!(
                p.held_out_transitions(),
                6,
                "one trajectory of task 0 held out, up to its first success (steps 0..=5)"
            );
            assert_eq!(p.buffer_len(), 12);
            p.check(true);
            let st = p.status(&["a", "b"]);
            assert!(st.tasks[0].spearman.is_some() && st.tasks[1].spearman.is_none());
            assert_eq!(st.tasks[0].validated, want, "threshold {threshold}");
            assert!(!st.tasks[1].validated, "no held-out data: never validated");
            assert_eq!(p.train(10).unwrap(), 0);
            p.train(12).unwrap();
            let w = p.weights_to_publish().unwrap().expect("a version");
            let tensors: std::collections::BTreeMap<String, Vec<f32>> = w
                .into_tensors()
                .into_iter()
                .map(|t| {
                    let (name, _, v) = t.into_parts();
                    (name, v)
                })
                .collect();
            assert_eq!(
                tensors[names::TEP_GATE],
                vec![f32::from(u8::from(want)), 0.0]
            );
            // Only the successful trajectory left a goal: the state after its first success.
            assert_eq!(tensors[names::TEP_GOAL_TASKS], vec![0.0]);
            let goal = &tensors[names::TEP_GOAL_STATES];
            assert_eq!(goal.len(), OBS_DIM);
            assert_eq!(goal[0], 6.0, "next_obs of step 5");
        }
    }
}
