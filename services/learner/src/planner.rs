//! The learner's TEP side (`algorithm = "terl"`): the TEP buffer fed by the selector's selected
//! samples (and optionally a dataset from an earlier run), TEP updates interleaved with SAC
//! updates, planner weights for the weight stream, planner checkpoints.

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

/// Running sums of the losses over the current reporting window.
#[derive(Debug, Default, Clone, Copy)]
struct LossWindow {
    f: f64,
    an: f64,
    target: f64,
    distance: f64,
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
}

fn sample_ok(s: &SelectedSample, num_tasks: usize) -> bool {
    usize::from(s.task) < num_tasks
        && s.obs.iter().chain(&s.next_obs).all(|v| v.is_finite())
        && s.action.iter().all(|a| a.is_finite() && a.abs() <= 1.0)
}

impl PlannerTrainer {
    pub(crate) fn new(mut config: TepConfig, num_tasks: usize, seed: u64) -> anyhow::Result<Self> {
        config.obs_dim = OBS_DIM;
        config.act_dim = ACTION_DIM;
        config.seed = seed;
        let tep = Tep::new(config.clone())?;
        Ok(Self {
            buffer: TepBuffer::new(config.buffer_capacity, OBS_DIM, ACTION_DIM),
            batch: TepBatch::with_capacity(config.batch_size, OBS_DIM, ACTION_DIM),
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x7e9_5a3d),
            tep,
            num_tasks,
            sac_offset: None,
            selected: 0,
            rejected: 0,
            window: LossWindow::default(),
            shown_f_loss: 0.0,
            shown_an_loss: 0.0,
            shown_target_mean: 0.0,
            shown_goal_distance_mean: 0.0,
            failed_updates: 0,
            published_version: 0,
        })
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
            let steps: Vec<u32> = seg.iter().map(|s| u32::from(s.step_index)).collect();
            let obs: Vec<f32> = seg.iter().flat_map(|s| s.obs).collect();
            let next_obs: Vec<f32> = seg.iter().flat_map(|s| s.next_obs).collect();
            let actions: Vec<f32> = seg.iter().flat_map(|s| s.action).collect();
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
        Ok(ran)
    }

    /// Closes the loss window (called with the learner's rate window).
    pub(crate) fn roll_window(&mut self) {
        if self.window.n > 0 {
            self.shown_f_loss = self.window.f / self.window.n as f64;
            self.shown_an_loss = self.window.an / self.window.n as f64;
            self.shown_target_mean = self.window.target / self.window.n as f64;
            self.shown_goal_distance_mean = self.window.distance / self.window.n as f64;
        }
        self.window = LossWindow::default();
    }

    /// Planner weights to publish, if TEP trained since the last publication.
    pub(crate) fn weights_to_publish(&mut self) -> anyhow::Result<Option<Weights>> {
        let version = self.tep.updates();
        if version == 0 || version == self.published_version {
            return Ok(None);
        }
        let weights = crate::to_weights(
            WeightsKind::Planner,
            version,
            version,
            self.tep.planner_tensors(),
        )?;
        self.published_version = version;
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
        let mut p = PlannerTrainer::new(small(), 2, 1).unwrap();
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

    #[test]
    fn trains_once_a_minibatch_is_there_and_publishes_new_versions_only() {
        let mut p = PlannerTrainer::new(small(), 1, 1).unwrap();
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
}
