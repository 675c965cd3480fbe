//! Inference-only policy for actors: the same network as the learner's, `f32`, sequential GEMMs
//! (actors run one per core), buffers preallocated for a fixed maximum batch.

use crate::config::SacConfig;
use crate::error::SacError;
use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rand::Rng;
use serde::{Deserialize, Serialize};
use terl_nn::tensors::TensorFile;
use terl_nn::{gaussian, Activation, Mlp, MlpSpec};

/// What an actor needs to rebuild the policy network: sizes only.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PolicySpec {
    pub obs_dim: usize,
    pub act_dim: usize,
    pub num_tasks: usize,
    pub hidden: Vec<usize>,
}

impl PolicySpec {
    pub fn from_config(cfg: &SacConfig) -> Self {
        Self {
            obs_dim: cfg.obs_dim,
            act_dim: cfg.act_dim,
            num_tasks: cfg.num_tasks,
            hidden: cfg.policy_hidden.clone(),
        }
    }

    pub(crate) fn mlp_spec(&self) -> MlpSpec {
        MlpSpec {
            input: self.obs_dim + self.num_tasks,
            hidden: self.hidden.clone(),
            output: 2 * self.act_dim,
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
    pub fn num_params(&self) -> usize {
        let mut sizes = vec![self.obs_dim + self.num_tasks];
        sizes.extend_from_slice(&self.hidden);
        sizes.push(2 * self.act_dim);
        sizes.windows(2).map(|w| w[0] * w[1] + w[1]).sum()
    }
}

/// A policy for acting: `act(obs, task_ids, deterministic)` on up to `max_batch` rows.
///
/// Small batches are a different GEMM regime from training: every weight is read once per call
/// for only a few rows. The policy therefore keeps its own copy of each weight packed for
/// small-batch products: transposed to `[in, out]` row-major, which faer multiplies without
/// repacking (about 1.4x faster than the training layout at 8 rows), and it skips the one-hot
/// columns of the first layer: multiplying by a one-hot vector is adding one weight column.
#[derive(Clone, Debug)]
pub struct Policy {
    spec: PolicySpec,
    net: Mlp<f32>,
    max_batch: usize,
    /// Per layer, the weight transposed to `[in, out]` (layer 0: observation rows only).
    weights_t: Vec<Vec<f32>>,
    /// First-layer weight columns of the one-hot inputs, `[task][out]`.
    onehot_cols: Vec<f32>,
    /// Per layer, activations of up to `max_batch` rows.
    acts: Vec<Vec<f32>>,
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
        let sizes = net.sizes().to_vec();
        let mut policy = Self {
            eps: vec![0.0; max_batch * spec.act_dim],
            log_prob: vec![0.0; max_batch],
            weights_t: Vec::new(),
            onehot_cols: Vec::new(),
            acts: sizes[1..]
                .iter()
                .map(|&s| vec![0.0; max_batch * s])
                .collect(),
            max_batch,
            spec,
            net,
            version: 0,
        };
        policy.pack_weights();
        policy
    }

    fn pack_weights(&mut self) {
        let sizes = self.net.sizes().to_vec();
        let od = self.spec.obs_dim;
        self.weights_t.clear();
        for l in 0..sizes.len() - 1 {
            let (n_in, n_out) = (sizes[l], sizes[l + 1]);
            let w = &self.net.params[self.net.weight_range(l)];
            let used_in = if l == 0 { od } else { n_in };
            let mut wt = vec![0.0; used_in * n_out];
            for o in 0..n_out {
                for i in 0..used_in {
                    wt[i * n_out + o] = w[o * n_in + i];
                }
            }
            self.weights_t.push(wt);
            if l == 0 {
                self.onehot_cols = (0..self.spec.num_tasks)
                    .flat_map(|t| (0..n_out).map(move |o| w[o * n_in + od + t]))
                    .collect();
            }
        }
    }

    pub fn spec(&self) -> &PolicySpec {
        &self.spec
    }

    /// Replaces the weights with a flat vector from [`crate::Sac::policy_params_f32`].
    pub fn set_params(&mut self, params: &[f32], version: u64) -> Result<(), SacError> {
        if params.len() != self.net.num_params() {
            return Err(SacError::Shape(format!(
                "policy weights have {} values, this policy needs {}",
                params.len(),
                self.net.num_params()
            )));
        }
        if params.iter().any(|v| !v.is_finite()) {
            return Err(SacError::Shape(
                "policy weights contain a non-finite value".into(),
            ));
        }
        self.net.params.copy_from_slice(params);
        self.pack_weights();
        self.version = version;
        Ok(())
    }

    /// Loads `policy.{layer}.weight|bias` tensors (as written by [`crate::Sac::policy_tensors`]).
    pub fn load(&mut self, file: &TensorFile, version: u64) -> Result<(), SacError> {
        self.net.import("policy", file)?;
        self.pack_weights();
        self.version = version;
        Ok(())
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
        let (od, a, nt) = (self.spec.obs_dim, self.spec.act_dim, self.spec.num_tasks);
        let rows = task_ids.len();
        if obs.len() != rows * od || actions.len() != rows * a || rows > self.max_batch {
            return Err(SacError::Shape(format!(
                "act: {} obs values, {} tasks, {} action slots for obs_dim {od}, act_dim {a}, max batch {}",
                obs.len(),
                rows,
                actions.len(),
                self.max_batch
            )));
        }
        if let Some(&t) = task_ids.iter().find(|&&t| t >= nt) {
            return Err(SacError::Shape(format!(
                "task id {t} out of range for {nt} tasks"
            )));
        }
        let sizes = self.net.sizes();
        let layers = sizes.len() - 1;
        for l in 0..layers {
            let (n_in, n_out) = (sizes[l], sizes[l + 1]);
            let (before, rest) = self.acts.split_at_mut(l);
            let y = &mut rest[0][..rows * n_out];
            let bias = &self.net.params[self.net.bias_range(l)];
            let hidden = l + 1 < layers;
            if l == 0 {
                matmul(
                    MatMut::from_row_major_slice_mut(y, rows, n_out),
                    Accum::Replace,
                    MatRef::from_row_major_slice(obs, rows, od),
                    MatRef::from_row_major_slice(&self.weights_t[0], od, n_out),
                    1.0f32,
                    Par::Seq,
                );
                for (row, &task) in y.chunks_exact_mut(n_out).zip(task_ids) {
                    let onehot_col = &self.onehot_cols[task * n_out..(task + 1) * n_out];
                    for ((v, &w), &b) in row.iter_mut().zip(onehot_col).zip(bias) {
                        let s = *v + w + b;
                        *v = if hidden && s < 0.0 { 0.0 } else { s };
                    }
                }
            } else {
                matmul(
                    MatMut::from_row_major_slice_mut(y, rows, n_out),
                    Accum::Replace,
                    MatRef::from_row_major_slice(&before[l - 1][..rows * n_in], rows, n_in),
                    MatRef::from_row_major_slice(&self.weights_t[l], n_in, n_out),
                    1.0f32,
                    Par::Seq,
                );
                for row in y.chunks_exact_mut(n_out) {
                    for (v, &b) in row.iter_mut().zip(bias) {
                        let s = *v + b;
                        *v = if hidden && s < 0.0 { 0.0 } else { s };
                    }
                }
            }
        }
        let head = &self.acts[layers - 1][..rows * 2 * a];
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
