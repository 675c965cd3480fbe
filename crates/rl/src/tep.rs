//! The Task-evoked Planner (paper Sec. IV.B): reachability net `F(s, s', a)` (steps from `s` to
//! `s'` when starting with action `a`) and Action Network `AN(s, s') ≈ argmin_a F(s, s', a)`, each
//! with a Polyak-averaged target copy `F̃`, `ÃN`.
//!
//! One update ([`Tep::update`]) on rows `(s_t, a_t, s_{t+1}, s')` computes, from the parameters
//! as they were at the start of the update,
//!
//! - F loss (Eq. 11/13, with the **plus** before the symmetry term — Eq. 13's minus is a typo):
//!   `L_F = mean[(F(s_t,s_{t+1},a_t) − 1)² + (F(s_t,s',a_t) − z)² + (F(s_t,s_{t+1},a_t) −
//!   F(s_{t+1},s_t,−a_t))²]`, `z = 1 + F̃(s_{t+1}, s', ÃN(s_{t+1}, s'))` (no gradient through `z`);
//! - AN loss (Eq. 14): `L_AN = mean F(s_t, s', AN(s_t, s'))` with F frozen: the gradient flows
//!   through F's action input into AN only; F's parameters get nothing from it;
//!
//! then steps both Adam optimisers and both targets. Any non-finite loss or gradient stops the
//! update with every weight unchanged.
//!
//! **One GEMM per layer for all F evaluations.** The three F terms and the AN loss all use the
//! current F weights, so their inputs are stacked into one `4B`-row matrix
//! (rows `0..B`: `(s_t, s_{t+1}, a_t)`, `B..2B`: `(s_t, s', a_t)`, `2B..3B`: `(s_{t+1}, s_t, −a_t)`,
//! `3B..4B`: `(s_t, s', AN(s_t, s'))`) and F runs one forward pass over it. Backward runs once over
//! rows `0..3B` with parameter gradients (the F loss) and once over `3B..4B` for the action-input
//! gradient only (the AN loss). The targets `ÃN → F̃` are a second, `B`-row chain.
//!
//! **F ≥ 0 by construction.** F is a number of steps (Eq. 10: `F ∈ ℝ₊`), so its output layer is
//! a softplus, `F = ln(1 + e^z) ≥ 0`; hence every bootstrapped target `z = 1 + F̃(..) ≥ 1`,
//! whatever the target network's weights. Chosen over clamping only the bootstrapped term at 0
//! because a clamp bounds the targets but not F itself: AN minimises F (Eq. 14), and with a
//! linear output it can find actions where F extrapolates below zero, off the data — exactly
//! the values guidance then compares. Softplus keeps both F and the targets in range with a
//! gradient everywhere (for large `z` it is the identity, so step counts up to an episode's
//! 500 are represented as before).

use crate::error::SacError;
use crate::names;
use crate::small_mlp::SmallBatchMlp;
use crate::tep_buffer::{GoalSampling, TepBatch};
use faer::Par;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use terl_nn::tensors::{Tensor, TensorFile};
use terl_nn::{
    clear_upper_state, par_for_threads, Activation, Adam, AdamConfig, Float, InputGrad, Mlp,
    MlpCache, MlpSpec,
};

pub use crate::limits::{MAX_BATCH, MAX_PARAMETERS, MAX_WIDTH};

/// Hyper-parameters of the planner. Network sizes, minibatch, buffer, τ and learning rates follow
/// the paper (3 × 512 ReLU, minibatch 1024, buffer 6M, τ = 0.005, lr 3e-4); the F target, its
/// loss weighting, the output scale, AN's behaviour-cloning weight and the hindsight sampling are
/// this implementation's means of making F a step count (each measured with `terl planner eval`,
/// `docs/results/planner/`). `TepConfig::paper()` is Eq. 11–14 exactly.
///
/// ```toml
/// f_hidden = [512, 512, 512]
/// an_hidden = [512, 512, 512]
/// batch_size = 1024
/// updates_per_sac_update = 1.0
/// f_target = "gap"               # or "bootstrap" (Eq. 11), "gap_bounded"
/// goal_loss = "relative"         # or "squared" (Eq. 11)
/// f_output_scale = 100.0
/// an_bc_weight = 1.0
/// near_goal_fraction = 0.5
/// near_goal_steps = 20
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TepConfig {
    /// Observation size (39 for Meta-World; no task id: the planner is task-agnostic).
    pub obs_dim: usize,
    /// Action size (4 for Meta-World).
    pub act_dim: usize,
    /// Hidden widths of F (ReLU); input `2·obs_dim + act_dim`, output 1 (softplus, so F ≥ 0).
    pub f_hidden: Vec<usize>,
    /// Hidden widths of AN (ReLU); input `2·obs_dim`, output `act_dim` (tanh).
    pub an_hidden: Vec<usize>,
    /// Adam learning rate of F.
    pub f_lr: f64,
    /// Adam learning rate of AN.
    pub an_lr: f64,
    /// Polyak factor of both targets (`target ← (1 − τ)·target + τ·net`).
    pub tau: f64,
    /// Rows per update (paper: 1024).
    pub batch_size: usize,
    /// TEP updates per SAC update in the learner (see [`TepConfig::updates_due`]).
    pub updates_per_sac_update: f64,
    /// Capacity of the TEP buffer in transitions (paper: 6M), oldest out.
    pub buffer_capacity: usize,
    /// Threads of the update's GEMMs (a private rayon pool when above 1).
    pub threads: usize,
    /// Seed of network initialisation.
    pub seed: u64,
    /// What the hindsight term of F's loss regresses on (see [`FTarget`]).
    pub f_target: FTarget,
    /// Weighting of the hindsight term (see [`GoalLoss`]).
    pub goal_loss: GoalLoss,
    /// `c` in `F = c · softplus(y)`: F's output in steps is the network's softplus output times
    /// `c`, so a network of unit-scale outputs represents step counts of an episode (up to 500)
    /// without its last layer having to grow by two orders of magnitude first. A planner file
    /// whose recorded config lacks it was written with 1 ([`TepConfig::from_saved_toml`]).
    pub f_output_scale: f64,
    /// `λ` of AN's behaviour-cloning term: `L_AN = mean F(s_t, s', AN(s_t, s')) / c + λ · mean
    /// ‖AN(s_t, s') − a_t‖²` (0 = Eq. 14; `c` = [`TepConfig::f_output_scale`], so λ weighs one
    /// step of F against one unit of squared action error). It keeps AN on the data's actions,
    /// where F was trained: minimising a learned F alone finds actions F has never seen.
    pub an_bc_weight: f64,
    /// Fraction of hindsight goals drawn within [`TepConfig::near_goal_steps`] steps of `s_t`
    /// (the rest uniformly over the later states of the trajectory; 0 = uniform as the paper).
    pub near_goal_fraction: f64,
    /// Horizon of the near hindsight goals, in steps (≥ 1).
    pub near_goal_steps: u32,
    /// A planner file to start from (`terl planner train --out`, the paper's planner "trained
    /// separately"); the learner refuses one whose networks or output scale differ from these.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init_planner: Option<String>,
}

/// Target `z` of the hindsight term `(F(s_t, s', a_t) − z)²` of F's loss; `k` is the known step
/// gap from `s_t` to `s'` along the trajectory ([`TepBatch::gaps`]), an upper bound of the true
/// distance (the trajectory is one way to get there).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FTarget {
    /// `z = 1 + F̃(s_{t+1}, s', ÃN(s_{t+1}, s'))` (paper Eq. 11): undiscounted and bootstrapped;
    /// with τ = 0.005 it grows by about one step per ~200 updates.
    Bootstrap,
    /// `z = min(k, 1 + F̃(s_{t+1}, s', ÃN(s_{t+1}, s')))`: the bootstrap bounded by the known gap
    /// (never above what the data shows; below it where the planner knows a shorter way).
    /// Measured on scripted MT10 data (`docs/results/planner/`): held-out ρ 0.93 against 0.98
    /// for [`FTarget::Gap`], relative errors 20/16/25 % against 13/7/7 % (gaps 1–10/11–30/31–100):
    /// the minimum takes the bootstrap where `ÃN` finds actions off the data whose `F̃` is
    /// small, so F underestimates.
    GapBounded,
    /// `z = k`: Monte-Carlo regression on the hindsight gap (no target networks). The default:
    /// on scripted MT10 data ρ = 0.976 on held-out variations (the paper's Eq. 11 target: 0.70).
    #[default]
    Gap,
}

/// Weighting of the hindsight term of F's loss.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalLoss {
    /// `(F − z)²` (paper Eq. 11): far goals dominate (an error of 10 % at 300 steps counts 900
    /// times one of 10 % at 10 steps).
    Squared,
    /// `(F − z)² / z`: errors count relative to the distance, so near and far goals are learned
    /// to a similar relative accuracy.
    #[default]
    Relative,
}

impl Default for TepConfig {
    fn default() -> Self {
        Self {
            obs_dim: 39,
            act_dim: 4,
            f_hidden: vec![512, 512, 512],
            an_hidden: vec![512, 512, 512],
            f_lr: 3e-4,
            an_lr: 3e-4,
            tau: 0.005,
            batch_size: 1024,
            updates_per_sac_update: 1.0,
            buffer_capacity: 6_000_000,
            threads: 1,
            seed: 0,
            f_target: FTarget::Gap,
            goal_loss: GoalLoss::Relative,
            f_output_scale: 100.0,
            an_bc_weight: 1.0,
            near_goal_fraction: 0.5,
            near_goal_steps: 20,
            init_planner: None,
        }
    }
}

impl TepConfig {
    /// The paper's planner exactly (Eq. 11–14): bootstrapped target, squared loss, unit output
    /// scale, no behaviour cloning, uniform hindsight goals.
    pub fn paper() -> Self {
        Self {
            f_target: FTarget::Bootstrap,
            goal_loss: GoalLoss::Squared,
            f_output_scale: 1.0,
            an_bc_weight: 0.0,
            near_goal_fraction: 0.0,
            ..Self::default()
        }
    }

    /// The hindsight sampling of [`TepBuffer::sample_into_with`].
    ///
    /// [`TepBuffer::sample_into_with`]: crate::TepBuffer::sample_into_with
    pub fn goal_sampling(&self) -> GoalSampling {
        GoalSampling {
            near_fraction: self.near_goal_fraction,
            near_steps: self.near_goal_steps,
        }
    }
}

impl TepConfig {
    /// Parses a TOML document (unknown keys are an error).
    pub fn from_toml(text: &str) -> Result<Self, SacError> {
        let cfg: Self = toml::from_str(text).map_err(|e| SacError::Config(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Parses the config recorded with a planner (`terl.tep_config` in a planner file's
    /// metadata). Keys missing there take the values of the version that wrote the file, where
    /// they change what the weights mean: `f_output_scale` = 1 (files before it existed).
    pub fn from_saved_toml(text: &str) -> Result<Self, SacError> {
        let table: toml::Table =
            toml::from_str(text).map_err(|e| SacError::Config(e.to_string()))?;
        let mut cfg = Self::from_toml(text)?;
        if !table.contains_key("f_output_scale") {
            cfg.f_output_scale = 1.0;
        }
        Ok(cfg)
    }

    /// Checks the configuration before anything is allocated: positive sizes, `tau` and the
    /// learning rates in range, widths at most [`MAX_WIDTH`] and at most 16 hidden layers, at
    /// most [`MAX_PARAMETERS`] parameters, `batch_size` at most [`MAX_BATCH`], finite
    /// non-negative `an_bc_weight` and `updates_per_sac_update`, `f_output_scale` in
    /// `[0.001, 10000]`, and the near-goal sampling in range.
    ///
    /// # Errors
    /// [`SacError::Config`] naming the first field that fails.
    pub fn validate(&self) -> Result<(), SacError> {
        let bad = |m: String| Err(SacError::Config(m));
        if self.obs_dim == 0 || self.act_dim == 0 || self.batch_size == 0 {
            return bad("tep obs_dim, act_dim and batch_size must be positive".into());
        }
        if self.f_hidden.contains(&0) || self.an_hidden.contains(&0) {
            return bad("tep hidden widths must be positive".into());
        }
        if !(0.0..=1.0).contains(&self.tau) {
            return bad(format!("tep tau {} not in [0, 1]", self.tau));
        }
        if !(self.updates_per_sac_update >= 0.0 && self.updates_per_sac_update.is_finite()) {
            return bad(format!(
                "tep updates_per_sac_update {} must be finite and ≥ 0",
                self.updates_per_sac_update
            ));
        }
        if self.buffer_capacity == 0 || self.threads == 0 {
            return bad("tep buffer_capacity and threads must be positive".into());
        }
        if self.threads > crate::limits::MAX_THREADS {
            return bad(format!(
                "tep threads {} must be at most {}",
                self.threads,
                crate::limits::MAX_THREADS
            ));
        }
        // The paper's buffer holds 6M samples; each is ~90 floats.
        const MAX_BUFFER_CAPACITY: usize = 50_000_000;
        if self.buffer_capacity > MAX_BUFFER_CAPACITY {
            return bad(format!(
                "tep buffer_capacity {} must be at most {MAX_BUFFER_CAPACITY}",
                self.buffer_capacity
            ));
        }
        if !(1e-3..=1e4).contains(&self.f_output_scale) {
            return bad(format!(
                "tep f_output_scale {} must be in [0.001, 10000] (steps per unit of the network's \
                 softplus output)",
                self.f_output_scale
            ));
        }
        for (name, lr) in [("f_lr", self.f_lr), ("an_lr", self.an_lr)] {
            if !(lr.is_finite() && lr > 0.0 && lr <= 1.0) {
                return bad(format!("tep {name} {lr} must be in (0, 1]"));
            }
        }
        if let Some(w) = self
            .f_hidden
            .iter()
            .chain(&self.an_hidden)
            .find(|&&w| w > MAX_WIDTH)
        {
            return bad(format!("tep hidden width {w} is above {MAX_WIDTH}"));
        }
        if self.f_hidden.len() > 16 || self.an_hidden.len() > 16 {
            return bad("tep networks have at most 16 hidden layers".into());
        }
        if self.obs_dim > MAX_WIDTH || self.act_dim > MAX_WIDTH {
            return bad(format!(
                "tep obs_dim {} / act_dim {} is above {MAX_WIDTH}",
                self.obs_dim, self.act_dim
            ));
        }
        let parameters = self.parameters();
        if parameters > MAX_PARAMETERS {
            return bad(format!(
                "tep networks F {:?} and AN {:?} have {parameters} parameters, above \
                 {MAX_PARAMETERS} (with their targets and Adam moments they would not fit in \
                 memory)",
                self.f_hidden, self.an_hidden
            ));
        }
        if self.batch_size > MAX_BATCH {
            return bad(format!(
                "tep batch_size {} is above {MAX_BATCH}",
                self.batch_size
            ));
        }
        if !(self.an_bc_weight.is_finite() && self.an_bc_weight >= 0.0) {
            return bad(format!(
                "tep an_bc_weight {} must be finite and ≥ 0",
                self.an_bc_weight
            ));
        }
        if !(0.0..=1.0).contains(&self.near_goal_fraction) || self.near_goal_steps == 0 {
            return bad(format!(
                "tep near_goal_fraction {} must be in [0, 1] and near_goal_steps {} ≥ 1",
                self.near_goal_fraction, self.near_goal_steps
            ));
        }
        Ok(())
    }

    /// Weights and biases of F and AN together (checked before anything is allocated).
    pub fn parameters(&self) -> usize {
        let count = |input: usize, hidden: &[usize], output: usize| -> usize {
            let mut widths = vec![input];
            widths.extend_from_slice(hidden);
            widths.push(output);
            widths
                .windows(2)
                .map(|w| w[0].saturating_mul(w[1]).saturating_add(w[1]))
                .fold(0usize, usize::saturating_add)
        };
        count(self.f_input(), &self.f_hidden, 1).saturating_add(count(
            self.an_input(),
            &self.an_hidden,
            self.act_dim,
        ))
    }

    /// Input width of F: `[s, s', a]`.
    pub fn f_input(&self) -> usize {
        2 * self.obs_dim + self.act_dim
    }

    /// Input width of AN: `[s, s']`.
    pub fn an_input(&self) -> usize {
        2 * self.obs_dim
    }

    /// Architecture of F: input `[s, s', a]` ([`Self::f_input`]), `f_hidden` ReLU layers, one
    /// softplus output (a step count, `F ≥ 0`; see the module docs).
    pub fn f_spec(&self) -> MlpSpec {
        MlpSpec {
            input: self.f_input(),
            hidden: self.f_hidden.clone(),
            output: 1,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Softplus,
        }
    }

    /// Architecture of AN: input `[s, s']` ([`Self::an_input`]), `an_hidden` ReLU layers, `act_dim`
    /// tanh outputs (an action in `[-1, 1]`).
    pub fn an_spec(&self) -> MlpSpec {
        MlpSpec {
            input: self.an_input(),
            hidden: self.an_hidden.clone(),
            output: self.act_dim,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Tanh,
        }
    }

    /// TEP updates to run now so that `tep_done ≈ ratio · sac_done` (never negative).
    pub fn updates_due(&self, sac_done: u64, tep_done: u64) -> u64 {
        let want = (self.updates_per_sac_update * sac_done as f64).floor() as u64;
        want.saturating_sub(tep_done)
    }
}

/// Losses and diagnostics of one TEP update.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TepStats {
    /// Total F loss (mean over rows of the three terms).
    pub f_loss: f64,
    /// Mean `(F(s_t,s_{t+1},a_t) − 1)²`.
    pub step_loss: f64,
    /// Mean `(F(s_t,s',a_t) − z)²`.
    pub goal_loss: f64,
    /// Mean `(F(s_t,s_{t+1},a_t) − F(s_{t+1},s_t,−a_t))²`.
    pub symmetry_loss: f64,
    /// AN loss's planning part: mean `F(s_t, s', AN(s_t, s'))` in steps (divided by the output
    /// scale in the optimised loss, see [`TepConfig::an_bc_weight`]).
    pub an_loss: f64,
    /// AN's behaviour-cloning term: mean `‖AN(s_t, s') − a_t‖²` (optimised with weight
    /// [`TepConfig::an_bc_weight`]).
    pub an_bc_loss: f64,
    /// Mean `F(s_t, s', a_t)` (predicted steps to the hindsight goal; ≥ 0).
    pub goal_distance_mean: f64,
    /// Mean bootstrapped target `z = 1 + F̃(s_{t+1}, s', ÃN(s_{t+1}, s'))` (≥ 1, see the module
    /// docs).
    pub target_mean: f64,
    /// Smallest bootstrapped target `z` of the batch (≥ 1).
    pub target_min: f64,
    /// Mean data distance `gap` of the batch.
    pub gap_mean: f64,
}

/// The planner learner: F, AN, targets, optimisers and update buffers.
#[derive(Debug)]
pub struct Tep<T: Float = f32> {
    config: TepConfig,
    f: Mlp<T>,
    f_target: Mlp<T>,
    an: Mlp<T>,
    an_target: Mlp<T>,
    f_adam: Adam<T>,
    an_adam: Adam<T>,
    f_grads: Vec<T>,
    an_grads: Vec<T>,
    /// The four stacked F evaluations (see the module docs), `4B` rows.
    f_cache: MlpCache<T>,
    f_target_cache: MlpCache<T>,
    an_cache: MlpCache<T>,
    an_target_cache: MlpCache<T>,
    pool: Option<rayon::ThreadPool>,
    updates: u64,
    rejected_batches: u64,
}

/// Copies `f32` values into `T`s.
#[inline]
fn put<T: Float>(dst: &mut [T], src: &[f32]) {
    for (d, &s) in dst.iter_mut().zip(src) {
        *d = T::of_f32(s);
    }
}

impl<T: Float> Tep<T> {
    /// F and AN initialised from `config.seed`, their targets as exact copies, Adam optimisers at
    /// `f_lr` and `an_lr`, and update buffers for `batch_size` rows (a thread pool of `threads`
    /// workers when above 1).
    ///
    /// # Errors
    /// [`SacError::Config`] if [`TepConfig::validate`] fails or the thread pool cannot be built.
    pub fn new(config: TepConfig) -> Result<Self, SacError> {
        config.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let f = Mlp::new(&config.f_spec(), &mut rng);
        let an = Mlp::new(&config.an_spec(), &mut rng);
        let b = config.batch_size;
        let pool = if config.threads > 1 {
            Some(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(config.threads)
                    .thread_name(|i| format!("tep-update-{i}"))
                    .build()
                    .map_err(|e| SacError::Config(format!("cannot build TEP thread pool: {e}")))?,
            )
        } else {
            None
        };
        Ok(Self {
            f_adam: Adam::new(f.num_params(), AdamConfig::with_lr(config.f_lr)),
            an_adam: Adam::new(an.num_params(), AdamConfig::with_lr(config.an_lr)),
            f_grads: vec![T::of(0.0); f.num_params()],
            an_grads: vec![T::of(0.0); an.num_params()],
            f_cache: MlpCache::new(&f, 4 * b),
            f_target_cache: MlpCache::new(&f, b),
            an_cache: MlpCache::new(&an, b),
            an_target_cache: MlpCache::new(&an, b),
            f_target: f.clone(),
            an_target: an.clone(),
            f,
            an,
            pool,
            updates: 0,
            rejected_batches: 0,
            config,
        })
    }

    /// The hyper-parameters this planner learner was built with.
    pub fn config(&self) -> &TepConfig {
        &self.config
    }

    /// Updates applied so far.
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Batches rejected for non-finite values.
    pub fn rejected_batches(&self) -> u64 {
        self.rejected_batches
    }

    /// The reachability network F (`[s, s', a] → steps`).
    pub fn f_net(&self) -> &Mlp<T> {
        &self.f
    }

    /// Mutable F; its target and Adam state are left as is.
    pub fn f_net_mut(&mut self) -> &mut Mlp<T> {
        &mut self.f
    }

    /// The Action Network AN (`[s, s'] → a`).
    pub fn an_net(&self) -> &Mlp<T> {
        &self.an
    }

    /// Mutable AN; its target and Adam state are left as is.
    pub fn an_net_mut(&mut self) -> &mut Mlp<T> {
        &mut self.an
    }

    /// The Polyak-averaged target F̃ (used only in the bootstrapped target `z`).
    pub fn f_target_net(&self) -> &Mlp<T> {
        &self.f_target
    }

    /// The target F̃, mutable (checkpoint loading, tests).
    pub fn f_target_net_mut(&mut self) -> &mut Mlp<T> {
        &mut self.f_target
    }

    /// The Polyak-averaged target ÃN (used only in the bootstrapped target `z`).
    pub fn an_target_net(&self) -> &Mlp<T> {
        &self.an_target
    }

    /// Gradients of the last computation: F (from the F loss), AN (from the AN loss).
    pub fn gradients(&self) -> (&[T], &[T]) {
        (&self.f_grads, &self.an_grads)
    }

    fn check_batch(&self, batch: &TepBatch) -> Result<(), SacError> {
        let c = &self.config;
        if batch.obs_dim != c.obs_dim || batch.act_dim != c.act_dim {
            return Err(SacError::Shape(format!(
                "TEP batch has obs/act dims {}/{}, config {}/{}",
                batch.obs_dim, batch.act_dim, c.obs_dim, c.act_dim
            )));
        }
        if batch.is_empty() || batch.len() > c.batch_size {
            return Err(SacError::Shape(format!(
                "TEP batch of {} rows; capacity is {}",
                batch.len(),
                c.batch_size
            )));
        }
        batch.check_shape()
    }

    /// One full update: reject a malformed or non-finite batch (non-finite ones are counted),
    /// compute both losses and gradients, and only if all are finite step F, AN and the targets.
    pub fn update(&mut self, batch: &TepBatch) -> Result<TepStats, SacError> {
        self.check_batch(batch)?;
        if let Err(e) = batch.check_finite() {
            self.rejected_batches += 1;
            return Err(e);
        }
        self.in_pool(|tep| {
            let stats = tep.compute_gradients_inner(batch)?;
            tep.apply_gradients();
            Ok(stats)
        })
    }

    /// Losses and gradients without changing any parameter (for gradient checks).
    pub fn compute_gradients(&mut self, batch: &TepBatch) -> Result<TepStats, SacError> {
        self.check_batch(batch)?;
        batch.check_finite()?;
        self.in_pool(|tep| tep.compute_gradients_inner(batch))
    }

    fn in_pool<R: Send>(&mut self, f: impl FnOnce(&mut Self) -> R + Send) -> R {
        let pool = self.pool.take();
        let r = match &pool {
            Some(pool) => pool.install(|| f(self)),
            None => f(self),
        };
        self.pool = pool;
        r
    }

    /// Forward pass of the target chain `ÃN(s_{t+1}, s')` → `F̃(s_{t+1}, s', ÃN(..))` into the
    /// target caches (raw softplus outputs, before the output scale).
    fn target_chain(&mut self, batch: &TepBatch, par: Par) {
        let (b, od, ad) = (batch.len(), self.config.obs_dim, self.config.act_dim);
        let (fw, aw) = (self.config.f_input(), self.config.an_input());
        let row = |i: usize| i * od..(i + 1) * od;
        let tin = self.an_target_cache.input_mut(0..b);
        for i in 0..b {
            let r = &mut tin[i * aw..(i + 1) * aw];
            put(&mut r[..od], &batch.next_obs[row(i)]);
            put(&mut r[od..], &batch.goals[row(i)]);
        }
        self.an_target.forward(&mut self.an_target_cache, b, par);
        let ta = self.an_target_cache.output(0..b);
        let fin = self.f_target_cache.input_mut(0..b);
        for i in 0..b {
            let r = &mut fin[i * fw..(i + 1) * fw];
            put(&mut r[..od], &batch.next_obs[row(i)]);
            put(&mut r[od..2 * od], &batch.goals[row(i)]);
            r[2 * od..].copy_from_slice(&ta[i * ad..(i + 1) * ad]);
        }
        self.f_target.forward(&mut self.f_target_cache, b, par);
    }

    #[allow(clippy::too_many_lines)] // one planner update's forward and backward passes in order (F, then AN), as the paper's Eq. 11-14
    fn compute_gradients_inner(&mut self, batch: &TepBatch) -> Result<TepStats, SacError> {
        let (b, od, ad) = (batch.len(), self.config.obs_dim, self.config.act_dim);
        let (fw, aw) = (self.config.f_input(), self.config.an_input());
        let par: Par = par_for_threads(self.config.threads);
        let inv_b = T::of(1.0 / b as f64);
        let two = T::of(2.0);
        let one = T::of(1.0);
        let c = T::of(self.config.f_output_scale);
        let bc = T::of(self.config.an_bc_weight);
        let (target_mode, relative) = (
            self.config.f_target,
            self.config.goal_loss == GoalLoss::Relative,
        );
        let row = |i: usize| i * od..(i + 1) * od;

        // Target chain (not needed for `z = k`).
        if target_mode != FTarget::Gap {
            self.target_chain(batch, par);
        }

        // AN(s_t, s').
        let ain = self.an_cache.input_mut(0..b);
        for i in 0..b {
            let r = &mut ain[i * aw..(i + 1) * aw];
            put(&mut r[..od], &batch.obs[row(i)]);
            put(&mut r[od..], &batch.goals[row(i)]);
        }
        self.an.forward(&mut self.an_cache, b, par);

        // The four stacked F evaluations.
        let an_out = self.an_cache.output(0..b);
        let fin = self.f_cache.input_mut(0..4 * b);
        for i in 0..b {
            let (s, s1, g) = (
                &batch.obs[row(i)],
                &batch.next_obs[row(i)],
                &batch.goals[row(i)],
            );
            let a = &batch.actions[i * ad..(i + 1) * ad];
            let r = &mut fin[i * fw..(i + 1) * fw];
            put(&mut r[..od], s);
            put(&mut r[od..2 * od], s1);
            put(&mut r[2 * od..], a);
            let r = &mut fin[(b + i) * fw..(b + i + 1) * fw];
            put(&mut r[..od], s);
            put(&mut r[od..2 * od], g);
            put(&mut r[2 * od..], a);
            let r = &mut fin[(2 * b + i) * fw..(2 * b + i + 1) * fw];
            put(&mut r[..od], s1);
            put(&mut r[od..2 * od], s);
            for (d, &v) in r[2 * od..].iter_mut().zip(a) {
                *d = -T::of_f32(v);
            }
            let r = &mut fin[(3 * b + i) * fw..(3 * b + i + 1) * fw];
            put(&mut r[..od], s);
            put(&mut r[od..2 * od], g);
            r[2 * od..].copy_from_slice(&an_out[i * ad..(i + 1) * ad]);
        }
        self.f.forward(&mut self.f_cache, 4 * b, par);

        // Losses and their gradients w.r.t. F's raw outputs y (F = c·y).
        let mut st = TepStats {
            target_min: f64::INFINITY,
            ..TepStats::default()
        };
        let f_next = self.f_target_cache.output(0..b);
        let (y, dy) = self.f_cache.output_and_grad_mut(0..4 * b);
        let (mut l1, mut l2, mut l3, mut l4) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for i in 0..b {
            let (y1, y2, y3, y4) = (c * y[i], c * y[b + i], c * y[2 * b + i], c * y[3 * b + i]);
            let gap = T::of(f64::from(batch.gaps[i]));
            let z = match target_mode {
                FTarget::Bootstrap => one + c * f_next[i],
                FTarget::GapBounded => gap.min(one + c * f_next[i]),
                FTarget::Gap => gap,
            };
            let w = if relative { one / z.max(one) } else { one };
            let e1 = y1 - one;
            let e2 = y2 - z;
            let e3 = y1 - y3;
            l1 += (e1 * e1).f64();
            l2 += (w * e2 * e2).f64();
            l3 += (e3 * e3).f64();
            l4 += y4.f64();
            st.goal_distance_mean += y2.f64();
            st.target_mean += z.f64();
            st.target_min = st.target_min.min(z.f64());
            dy[i] = c * two * (e1 + e3) * inv_b;
            dy[b + i] = c * two * w * e2 * inv_b;
            dy[2 * b + i] = -c * two * e3 * inv_b;
            // L_AN's F part is mean F / c = mean y.
            dy[3 * b + i] = inv_b;
        }
        let nb = b as f64;
        st.step_loss = l1 / nb;
        st.goal_loss = l2 / nb;
        st.symmetry_loss = l3 / nb;
        st.f_loss = (l1 + l2 + l3) / nb;
        st.an_loss = l4 / nb;
        st.goal_distance_mean /= nb;
        st.target_mean /= nb;
        st.gap_mean = batch.gaps.iter().map(|&g| g as f64).sum::<f64>() / nb;
        for (loss, value) in [("tep f", st.f_loss), ("tep an", st.an_loss)] {
            if !value.is_finite() {
                return Err(SacError::NonFiniteLoss { loss, value });
            }
        }

        // Backward: F's parameters from the F loss (rows 0..3B); AN through F's action input
        // (rows 3B..4B, no parameter gradient: F is frozen for the AN loss).
        self.f.backward(
            &mut self.f_cache,
            0..3 * b,
            Some(&mut self.f_grads),
            InputGrad::None,
            par,
        );
        self.f.backward(
            &mut self.f_cache,
            3 * b..4 * b,
            None,
            InputGrad::Cols(2 * od..fw),
            par,
        );
        let gin = self.f_cache.grad_input(3 * b..4 * b);
        let (an_out, dan) = self.an_cache.output_and_grad_mut(0..b);
        let mut bc_sum = 0.0f64;
        for i in 0..b {
            let d = &mut dan[i * ad..(i + 1) * ad];
            d.copy_from_slice(&gin[i * fw + 2 * od..(i + 1) * fw]);
            for (k, dk) in d.iter_mut().enumerate() {
                let e = an_out[i * ad + k] - T::of_f32(batch.actions[i * ad + k]);
                bc_sum += (e * e).f64();
                *dk += two * bc * e * inv_b;
            }
        }
        st.an_bc_loss = bc_sum / nb;
        self.an.backward(
            &mut self.an_cache,
            0..b,
            Some(&mut self.an_grads),
            InputGrad::None,
            par,
        );
        for (network, g) in [("tep F", &self.f_grads), ("tep AN", &self.an_grads)] {
            if !g.iter().all(|v| v.is_finite()) {
                return Err(SacError::NonFiniteGradient { network });
            }
        }
        Ok(st)
    }

    /// Steps F and AN and moves their targets; the two networks side by side when the update
    /// has more than one thread (called inside the pool).
    fn apply_gradients(&mut self) {
        let tau = T::of(self.config.tau);
        let mut f_step = || {
            clear_upper_state();
            self.f_adam.step(&mut self.f.params, &self.f_grads);
            self.f_target.polyak_from(&self.f, tau);
        };
        let mut an_step = || {
            clear_upper_state();
            self.an_adam.step(&mut self.an.params, &self.an_grads);
            self.an_target.polyak_from(&self.an, tau);
        };
        if self.config.threads > 1 {
            rayon::join(f_step, an_step);
        } else {
            f_step();
            an_step();
        }
        self.updates += 1;
    }

    /// FLOPs of the GEMMs of one update with `batch` rows.
    pub fn update_flops(&self, batch: usize) -> u64 {
        let b = batch;
        let ad = self.config.act_dim;
        self.an.forward_flops(b) * 2
            + self.f.forward_flops(b)
            + self.f.forward_flops(4 * b)
            + self.f.backward_flops(3 * b, true, 0)
            + self.f.backward_flops(b, false, ad)
            + self.an.backward_flops(b, true, 0)
    }

    /// Planner weights as flat `f32` (F, AN) in the [`Mlp`] layout, for the weight stream.
    pub fn planner_params_f32(&self) -> (Vec<f32>, Vec<f32>) {
        (
            self.f.params.iter().map(|v| v.f32()).collect(),
            self.an.params.iter().map(|v| v.f32()).collect(),
        )
    }

    /// Planner weights as named `f32` tensors `tep_f.{l}.weight|bias`, `tep_an.{l}.…`.
    pub fn planner_tensors(&self) -> Vec<Tensor> {
        let (f, an) = self.planner_params_f32();
        let mut out = Vec::new();
        self.f.export_values(names::TEP_F, &f, &mut out);
        self.an.export_values(names::TEP_AN, &an, &mut out);
        out
    }

    /// All state of the planner learner as named tensors, for resuming: F and AN
    /// (`tep_f.*`, `tep_an.*`), their targets (`tep_f_target.*`, `tep_an_target.*`), both Adam
    /// states (`tep_f_adam.*`, `tep_an_adam.*`) and `tep_counters` = `[updates,
    /// rejected_batches]` (i64). Restored by [`Tep::restore_checkpoint`].
    pub fn checkpoint_tensors(&self) -> Vec<Tensor> {
        let mut t = Vec::new();
        self.f.export(names::TEP_F, &mut t);
        self.an.export(names::TEP_AN, &mut t);
        self.f_target.export(names::TEP_F_TARGET, &mut t);
        self.an_target.export(names::TEP_AN_TARGET, &mut t);
        self.f_adam.export("tep_f_adam", &mut t);
        self.an_adam.export("tep_an_adam", &mut t);
        t.push(Tensor::from_i64(
            "tep_counters",
            vec![2],
            &[self.updates as i64, self.rejected_batches as i64],
        ));
        t
    }

    /// Restores state written by [`Tep::checkpoint_tensors`]. Shapes and dtypes must match this
    /// planner's config (an error names the first tensor that does not); on error nothing is
    /// changed.
    pub fn restore_checkpoint(&mut self, file: &TensorFile) -> Result<(), SacError> {
        let (mut f, mut an) = (self.f.clone(), self.an.clone());
        let (mut f_target, mut an_target) = (self.f_target.clone(), self.an_target.clone());
        let (mut f_adam, mut an_adam) = (self.f_adam.clone(), self.an_adam.clone());
        f.import(names::TEP_F, file)?;
        an.import(names::TEP_AN, file)?;
        f_target.import(names::TEP_F_TARGET, file)?;
        an_target.import(names::TEP_AN_TARGET, file)?;
        f_adam.import("tep_f_adam", file)?;
        an_adam.import("tep_an_adam", file)?;
        let counters = file.i64_values("tep_counters", &[2])?;
        self.f = f;
        self.an = an;
        self.f_target = f_target;
        self.an_target = an_target;
        self.f_adam = f_adam;
        self.an_adam = an_adam;
        self.updates = counters[0].max(0) as u64;
        self.rejected_batches = counters[1].max(0) as u64;
        Ok(())
    }

    /// Loads a planner file (`checkpoints/planner.safetensors`, `terl planner train --out`): F and
    /// AN, and their targets when the file has them (else copies of F and AN). Optimiser state
    /// and counters start afresh. Shapes must match this planner's config; on error nothing is
    /// changed.
    pub fn import_planner(&mut self, file: &TensorFile) -> Result<(), SacError> {
        let (mut f, mut an) = (self.f.clone(), self.an.clone());
        f.import(names::TEP_F, file)?;
        an.import(names::TEP_AN, file)?;
        let has_targets = file
            .tensors
            .keys()
            .any(|k| k.starts_with(&format!("{}.", names::TEP_F_TARGET)));
        let (mut f_target, mut an_target) = (f.clone(), an.clone());
        if has_targets {
            f_target.import(names::TEP_F_TARGET, file)?;
            an_target.import(names::TEP_AN_TARGET, file)?;
        }
        self.f = f;
        self.an = an;
        self.f_target = f_target;
        self.an_target = an_target;
        Ok(())
    }

    /// F, AN and both targets as named tensors (`tep_f.*`, `tep_an.*`, `tep_f_target.*`,
    /// `tep_an_target.*`): the tensors of a planner file (see [`Tep::import_planner`]).
    pub fn planner_file_tensors(&self) -> Vec<Tensor> {
        let mut t = Vec::new();
        self.f.export(names::TEP_F, &mut t);
        self.an.export(names::TEP_AN, &mut t);
        self.f_target.export(names::TEP_F_TARGET, &mut t);
        self.an_target.export(names::TEP_AN_TARGET, &mut t);
        t
    }

    /// An inference planner with these weights for up to `max_rows` rows per call.
    pub fn planner(&self, max_rows: usize) -> Planner {
        let mut p = Planner::new(&self.config, max_rows);
        let (f, an) = self.planner_params_f32();
        p.set_params(&f, &an, self.updates)
            .expect("planner shapes come from the same config");
        p
    }
}

/// Inference-only planner for actors: `F(s, g, a)` and `AN(s, g)` over small batches, `f32`,
/// sequential GEMMs on weights packed for few rows (see `SmallBatchMlp`), no allocation per
/// call.
#[derive(Debug)]
pub struct Planner {
    obs_dim: usize,
    act_dim: usize,
    f: Mlp<f32>,
    an: Mlp<f32>,
    f_small: SmallBatchMlp,
    an_small: SmallBatchMlp,
    /// Input rows `[s, g, a]` of F and `[s, g]` of AN.
    f_input: Vec<f32>,
    an_input: Vec<f32>,
    /// F's output scale ([`TepConfig::f_output_scale`]): `F = c · softplus(y)`.
    f_scale: f32,
    version: u64,
}

impl Planner {
    /// A planner with freshly initialised (untrained) weights; load real ones with
    /// [`Planner::set_params`].
    pub fn new(config: &TepConfig, max_rows: usize) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let f: Mlp<f32> = Mlp::new(&config.f_spec(), &mut rng);
        let an: Mlp<f32> = Mlp::new(&config.an_spec(), &mut rng);
        Self {
            obs_dim: config.obs_dim,
            act_dim: config.act_dim,
            f_small: SmallBatchMlp::new(&config.f_spec(), &f, max_rows),
            an_small: SmallBatchMlp::new(&config.an_spec(), &an, max_rows),
            f_input: vec![0.0; max_rows * config.f_input()],
            an_input: vec![0.0; max_rows * config.an_input()],
            f,
            an,
            f_scale: config.f_output_scale as f32,
            version: 0,
        }
    }

    /// Replaces the weights (flat, [`Tep::planner_params_f32`] layout); on error nothing changes.
    pub fn set_params(&mut self, f: &[f32], an: &[f32], version: u64) -> Result<(), SacError> {
        if f.len() != self.f.num_params() || an.len() != self.an.num_params() {
            return Err(SacError::Shape(format!(
                "planner weights of {} + {} values; expected {} + {}",
                f.len(),
                an.len(),
                self.f.num_params(),
                self.an.num_params()
            )));
        }
        if f.iter().chain(an).any(|v| !v.is_finite()) {
            return Err(SacError::Shape("planner weights are not finite".into()));
        }
        self.f.params.copy_from_slice(f);
        self.an.params.copy_from_slice(an);
        self.f_small.load(&self.f);
        self.an_small.load(&self.an);
        self.version = version;
        Ok(())
    }

    /// Version given with the last [`Planner::set_params`].
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Rows one call can evaluate.
    pub fn max_rows(&self) -> usize {
        self.f_small.max_rows()
    }

    /// `out[i] = F(obs_i, goal_i, action_i)` for `out.len()` rows.
    pub fn reach(&mut self, obs: &[f32], goals: &[f32], actions: &[f32], out: &mut [f32]) {
        let (n, od, ad) = (out.len(), self.obs_dim, self.act_dim);
        assert!(obs.len() == n * od && goals.len() == n * od && actions.len() == n * ad);
        let w = 2 * od + ad;
        let x = &mut self.f_input[..n * w];
        for i in 0..n {
            let r = &mut x[i * w..(i + 1) * w];
            r[..od].copy_from_slice(&obs[i * od..(i + 1) * od]);
            r[od..2 * od].copy_from_slice(&goals[i * od..(i + 1) * od]);
            r[2 * od..].copy_from_slice(&actions[i * ad..(i + 1) * ad]);
        }
        let c = self.f_scale;
        for (o, &y) in out.iter_mut().zip(self.f_small.forward(x, n)) {
            *o = c * y;
        }
    }

    /// `out` rows = `AN(obs_i, goal_i)` (`out.len() / act_dim` rows).
    pub fn actions(&mut self, obs: &[f32], goals: &[f32], out: &mut [f32]) {
        let (od, ad) = (self.obs_dim, self.act_dim);
        let n = out.len() / ad;
        assert!(obs.len() == n * od && goals.len() == n * od && out.len() == n * ad);
        let x = &mut self.an_input[..n * 2 * od];
        for i in 0..n {
            x[i * 2 * od..i * 2 * od + od].copy_from_slice(&obs[i * od..(i + 1) * od]);
            x[i * 2 * od + od..(i + 1) * 2 * od].copy_from_slice(&goals[i * od..(i + 1) * od]);
        }
        out.copy_from_slice(self.an_small.forward(x, n));
    }
}
