//! Inference-only policy for actors: the same network as the learner's, `f32`, sequential GEMMs
//! (actors run one per core), buffers preallocated for a fixed maximum batch.

use crate::care::{CareConfig, CarePolicy};
use crate::config::SacConfig;
use crate::error::SacError;
use crate::small_mlp::SmallBatchMlp;
use rand::Rng;
use serde::{Deserialize, Serialize};
use terl_nn::tensors::TensorFile;
use terl_nn::{gaussian, Activation, Mlp, MlpSpec};

/// What an actor needs to rebuild the policy network: sizes only.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolicySpec {
    /// Observation length without the task one-hot (39 for Meta-World).
    pub obs_dim: usize,
    /// Action length (4 for Meta-World).
    pub act_dim: usize,
    /// Number of tasks: the length of the one-hot appended to the observation.
    pub num_tasks: usize,
    /// Widths of the hidden layers.
    pub hidden: Vec<usize>,
    /// CARE's encoder in front of the network (`None`: MTSAC's `[obs, one-hot]` input).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub care: Option<CareConfig>,
}

impl PolicySpec {
    /// The policy's sizes from the training configuration (`obs_dim`, `act_dim`, `num_tasks`,
    /// `policy_hidden`).
    pub fn from_config(cfg: &SacConfig) -> Self {
        Self {
            obs_dim: cfg.obs_dim,
            act_dim: cfg.act_dim,
            num_tasks: cfg.num_tasks,
            hidden: cfg.policy_hidden.clone(),
            care: cfg.care.clone(),
        }
    }

    /// Width of the network's input: observation and one-hot, or CARE's front.
    fn input_dim(&self) -> Option<usize> {
        match &self.care {
            Some(c) => c.feature_dim.checked_add(c.encoding_dim),
            None => self.obs_dim.checked_add(self.num_tasks),
        }
    }

    /// Length of one explicit task-encoding row of [`Policy::act_encoded`]: `num_tasks` (a
    /// one-hot-like row) or, with CARE, its context length (768 for task embeddings).
    pub fn task_encoding_dim(&self) -> usize {
        match &self.care {
            Some(c) => c.context_dim(self.num_tasks),
            None => self.num_tasks,
        }
    }

    pub(crate) fn mlp_spec(&self) -> MlpSpec {
        MlpSpec {
            input: self
                .input_dim()
                .expect("policy input width overflows usize"),
            output: 2 * self.act_dim,
            ..self.mlp_spec_unchecked()
        }
    }

    /// The head's hidden layers and activations (input and output widths left 0).
    fn mlp_spec_unchecked(&self) -> MlpSpec {
        MlpSpec {
            input: 0,
            hidden: self.hidden.clone(),
            output: 0,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Identity,
        }
    }

    /// A network of this shape with placeholder weights.
    pub(crate) fn build_mlp(&self) -> Mlp<f32> {
        use rand::SeedableRng;
        Mlp::new(
            &self.mlp_spec(),
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(0),
        )
    }

    /// Number of `f32` parameters of the flat weight vector.
    ///
    /// # Panics
    /// If the count overflows `usize` (see [`Self::checked_num_params`] for sizes read from
    /// untrusted files).
    pub fn num_params(&self) -> usize {
        self.checked_num_params()
            .expect("policy parameter count overflows usize")
    }

    /// [`Self::num_params`], or `None` when the sizes overflow `usize`.
    pub fn checked_num_params(&self) -> Option<usize> {
        let head = MlpSpec {
            input: self.input_dim()?,
            output: self.act_dim.checked_mul(2)?,
            ..self.mlp_spec_unchecked()
        }
        .checked_num_params()?;
        match &self.care {
            Some(c) => head.checked_add(c.policy_num_params(self.obs_dim, self.num_tasks)?),
            None => Some(head),
        }
    }
}

/// A policy for acting: `act(obs, task_ids, deterministic)` on up to `max_batch` rows.
///
/// Small batches are a different GEMM regime from training: every weight is read once per call
/// for only a few rows. The policy therefore keeps its own copy of the weights packed in panels
/// for a register-blocked small-batch kernel (`SmallBatchMlp`), which streams each weight once
/// per call.
#[derive(Clone, Debug)]
pub struct Policy {
    spec: PolicySpec,
    net: Mlp<f32>,
    /// The network's weights packed for small batches.
    small: SmallBatchMlp,
    /// Network input rows (observation, then the one-hot task id; with CARE its front).
    input: Vec<f32>,
    /// CARE's encoder in front of the network.
    care: Option<CarePolicy>,
    eps: Vec<f32>,
    log_prob: Vec<f32>,
    /// Version of the loaded weights (set by the caller, e.g. the learner's update count).
    pub version: u64,
}

impl Policy {
    /// A policy of this shape for batches of up to `max_batch` observations; weights are a
    /// placeholder until [`Policy::set_params`] or [`Policy::load`].
    pub fn new(spec: PolicySpec, max_batch: usize) -> Self {
        let net = spec.build_mlp();
        let small = SmallBatchMlp::new(&spec.mlp_spec(), &net, max_batch);
        Self {
            eps: vec![0.0; max_batch * spec.act_dim],
            log_prob: vec![0.0; max_batch],
            input: vec![0.0; max_batch * spec.mlp_spec().input],
            care: spec
                .care
                .as_ref()
                .map(|c| CarePolicy::new(c, spec.obs_dim, spec.num_tasks, max_batch)),
            small,
            spec,
            net,
            version: 0,
        }
    }

    fn pack_weights(&mut self) {
        self.small.load(&self.net);
    }

    /// The sizes this policy was built with.
    pub fn spec(&self) -> &PolicySpec {
        &self.spec
    }

    /// The SIMD level of the small-batch kernel (the best this processor has).
    pub fn instruction_set(&self) -> terl_nn::InstructionSet {
        self.small.instruction_set()
    }

    /// Replaces the weights with a flat vector from [`crate::Sac::policy_params_f32`].
    pub fn set_params(&mut self, params: &[f32], version: u64) -> Result<(), SacError> {
        let needed = self.spec.num_params();
        if params.len() != needed {
            return Err(SacError::Shape(format!(
                "policy weights have {} values, this policy needs {needed}",
                params.len(),
            )));
        }
        if params.iter().any(|v| !v.is_finite()) {
            return Err(SacError::Shape(
                "policy weights contain a non-finite value".into(),
            ));
        }
        let (head, rest) = params.split_at(self.net.num_params());
        self.net.params.copy_from_slice(head);
        if let Some(care) = &mut self.care {
            care.set_params(rest);
        }
        self.pack_weights();
        self.version = version;
        Ok(())
    }

    /// Loads `policy.{layer}.weight|bias` tensors (as written by [`crate::Sac::policy_tensors`];
    /// with CARE also its experts, actor attention, task encoder and context table). On error
    /// nothing is changed.
    pub fn load(&mut self, file: &TensorFile, version: u64) -> Result<(), SacError> {
        let mut net = self.net.clone();
        net.import(crate::names::POLICY, file)?;
        if let Some(care) = &mut self.care {
            care.load(file)?;
        }
        self.net = net;
        self.pack_weights();
        self.version = version;
        Ok(())
    }

    /// A copy of this policy (same weights and version) for batches of up to `max_batch` rows,
    /// e.g. one per evaluation thread.
    pub fn with_max_batch(&self, max_batch: usize) -> Self {
        let mut p = Self::new(self.spec.clone(), max_batch);
        p.net.params.copy_from_slice(&self.net.params);
        if let (Some(d), Some(s)) = (&mut p.care, &self.care) {
            d.copy_from(s);
        }
        p.pack_weights();
        p.version = self.version;
        p
    }

    /// Width of one network input row.
    fn small_input(&self) -> usize {
        self.net.input_dim()
    }

    /// With CARE, task `task`'s row of the context table (what [`Policy::act`] encodes for
    /// it); `None` without CARE or for a task id out of range.
    pub fn care_context(&self, task: usize) -> Option<&[f32]> {
        self.care.as_ref().and_then(|c| c.context_row(task))
    }

    /// Largest batch [`Policy::act`] accepts.
    pub fn max_batch(&self) -> usize {
        self.small.max_rows()
    }

    /// Actions for `obs` (rows × obs_dim, row-major) of tasks `task_ids`, written to `actions`
    /// (rows × act_dim). Stochastic actions draw their noise from `rng`; deterministic ones are
    /// `tanh(mean)`.
    pub fn act(
        &mut self,
        obs: &[f32],
        task_ids: &[usize],
        deterministic: bool,
        rng: &mut impl Rng,
        actions: &mut [f32],
    ) -> Result<(), SacError> {
        let nt = self.spec.num_tasks;
        if let Some(&t) = task_ids.iter().find(|&&t| t >= nt) {
            return Err(SacError::Shape(format!(
                "task id {t} out of range for {nt} tasks"
            )));
        }
        self.act_with(
            obs,
            task_ids.len(),
            Ok(task_ids),
            deterministic,
            rng,
            actions,
        )
    }

    /// Like [`Policy::act`], with the task part of each input row given as a vector instead of
    /// a task id: `task_encodings` is rows × [`PolicySpec::task_encoding_dim`] (row-major). For
    /// MTSAC a one-hot row is exactly `act`; other rows (e.g. uniform `1/num_tasks`, or zeros)
    /// condition the policy on a task it was not trained on (zero-shot evaluation). With CARE
    /// a row is a task context (its description embedding through a ReLU,
    /// [`crate::care::context_table`]), so a new task is given by its own description.
    pub fn act_encoded(
        &mut self,
        obs: &[f32],
        task_encodings: &[f32],
        deterministic: bool,
        rng: &mut impl Rng,
        actions: &mut [f32],
    ) -> Result<(), SacError> {
        let nt = self.spec.task_encoding_dim();
        let rows = task_encodings.len() / nt.max(1);
        if task_encodings.len() != rows * nt {
            return Err(SacError::Shape(format!(
                "act_encoded: {} task-encoding values is not a whole number of rows of {nt}",
                task_encodings.len()
            )));
        }
        if task_encodings.iter().any(|v| !v.is_finite()) {
            return Err(SacError::Shape(
                "act_encoded: a task encoding has a non-finite value".into(),
            ));
        }
        self.act_with(obs, rows, Err(task_encodings), deterministic, rng, actions)
    }

    fn act_with(
        &mut self,
        obs: &[f32],
        rows: usize,
        tasks: Result<&[usize], &[f32]>,
        deterministic: bool,
        rng: &mut impl Rng,
        actions: &mut [f32],
    ) -> Result<(), SacError> {
        let (od, a, nt) = (self.spec.obs_dim, self.spec.act_dim, self.spec.num_tasks);
        if obs.len() != rows * od || actions.len() != rows * a || rows > self.small.max_rows() {
            return Err(SacError::Shape(format!(
                "act: {} obs values, {} tasks, {} action slots for obs_dim {od}, act_dim {a}, max batch {}",
                obs.len(),
                rows,
                actions.len(),
                self.small.max_rows()
            )));
        }
        let w = self.small_input();
        let input = &mut self.input[..rows * w];
        if let Some(care) = &mut self.care {
            care.front(obs, rows, tasks, input);
        } else {
            for (r, (row, o)) in input
                .chunks_exact_mut(w)
                .zip(obs.chunks_exact(od))
                .enumerate()
            {
                let (x, task) = row.split_at_mut(od);
                x.copy_from_slice(o);
                match tasks {
                    Ok(ids) => {
                        task.fill(0.0);
                        task[ids[r]] = 1.0;
                    }
                    Err(enc) => task.copy_from_slice(&enc[r * nt..(r + 1) * nt]),
                }
            }
        }
        let head = self.small.forward(input, rows);
        if deterministic {
            gaussian::mean_action(head, a, actions);
        } else {
            let eps = &mut self.eps[..rows * a];
            gaussian::fill_standard_normal(rng, eps);
            gaussian::sample(head, eps, a, actions, &mut self.log_prob[..rows]);
        }
        Ok(())
    }
}
