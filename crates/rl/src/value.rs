//! State values and policy entropies for PTR scoring (paper Sec. IV.A), from the learner's
//! current policy and twin critics as they arrive on the weight stream.
//!
//! - `V(s) = min(Q₁, Q₂)(s, tanh(μ(s)))`: the critics at the policy's deterministic action. SAC's
//!   soft value would add `−α·log π` of sampled actions; PTR only ranks transitions of gated
//!   tasks against each other, and the deterministic form needs no noise, so equal inputs give
//!   equal priorities.
//! - `H(s)`: entropy of the policy actually executed at `s`, the tanh-squashed Gaussian
//!   ([`crate::ptr::squashed_gaussian_entropy`] of the mean and the clamped log-std head:
//!   `E[−log π(a|s)]` including the tanh Jacobian).
//!
//! Forward passes run in `f32`, `max_rows` rows at a time, on the calling thread.

use crate::config::SacConfig;
use crate::error::SacError;
use crate::policy::PolicySpec;
use crate::ptr::squashed_gaussian_entropy;
use faer::Par;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_nn::gaussian::{LOG_STD_MAX, LOG_STD_MIN};
use terl_nn::{Activation, Mlp, MlpCache, MlpSpec};

/// Policy plus twin critics, forward-only.
#[derive(Clone, Debug)]
pub struct ValueEstimator {
    obs_dim: usize,
    act_dim: usize,
    num_tasks: usize,
    max_rows: usize,
    policy: Mlp<f32>,
    critics: [Mlp<f32>; 2],
    policy_cache: MlpCache<f32>,
    critic_cache: MlpCache<f32>,
    actions: Vec<f32>,
    policy_version: u64,
    critic_version: u64,
}

fn load(net: &mut Mlp<f32>, params: &[f32], what: &str) -> Result<(), SacError> {
    if params.len() != net.num_params() {
        return Err(SacError::Shape(format!(
            "{what} weights have {} values, the network needs {}",
            params.len(),
            net.num_params()
        )));
    }
    if let Some(i) = params.iter().position(|v| !v.is_finite()) {
        return Err(SacError::Shape(format!(
            "{what} weight {i} is not finite ({})",
            params[i]
        )));
    }
    net.params.copy_from_slice(params);
    Ok(())
}

impl ValueEstimator {
    /// Networks shaped as in `cfg` (placeholder weights until both setters ran), evaluating up
    /// to `max_rows` states per forward pass.
    pub fn new(cfg: &SacConfig, max_rows: usize) -> Self {
        let max_rows = max_rows.max(1);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let policy = PolicySpec::from_config(cfg).build_mlp();
        let critic_spec = MlpSpec {
            input: cfg.critic_input(),
            hidden: cfg.critic_hidden.clone(),
            output: 1,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Identity,
        };
        let critics = [
            Mlp::new(&critic_spec, &mut rng),
            Mlp::new(&critic_spec, &mut rng),
        ];
        Self {
            obs_dim: cfg.obs_dim,
            act_dim: cfg.act_dim,
            num_tasks: cfg.num_tasks,
            max_rows,
            policy_cache: MlpCache::new(&policy, max_rows),
            critic_cache: MlpCache::new(&critics[0], max_rows),
            actions: vec![0.0; max_rows * cfg.act_dim],
            policy,
            critics,
            policy_version: 0,
            critic_version: 0,
        }
    }

    /// Loads policy weights (the flat layout of [`crate::Sac::policy_params_f32`]).
    pub fn set_policy(&mut self, params: &[f32], version: u64) -> Result<(), SacError> {
        load(&mut self.policy, params, "policy")?;
        self.policy_version = version;
        Ok(())
    }

    /// Loads both critics: the values of [`crate::Sac::critic_tensors`] concatenated in order
    /// (qf1's parameters, then qf2's).
    pub fn set_critics(&mut self, params: &[f32], version: u64) -> Result<(), SacError> {
        let n = self.critics[0].num_params();
        if params.len() != 2 * n {
            return Err(SacError::Shape(format!(
                "critic weights have {} values, two critics need {}",
                params.len(),
                2 * n
            )));
        }
        let (q1, q2) = params.split_at(n);
        let mut fresh = self.critics.clone();
        load(&mut fresh[0], q1, crate::names::CRITICS[0])?;
        load(&mut fresh[1], q2, crate::names::CRITICS[1])?;
        self.critics = fresh;
        self.critic_version = version;
        Ok(())
    }

    /// Whether real weights for both the policy and the critics were loaded.
    pub fn is_ready(&self) -> bool {
        self.policy_version > 0 && self.critic_version > 0
    }

    /// Version of the policy weights last loaded by [`Self::set_policy`]; 0 until the first load.
    pub fn policy_version(&self) -> u64 {
        self.policy_version
    }

    /// Version of the critic weights last loaded by [`Self::set_critics`]; 0 until the first load.
    pub fn critic_version(&self) -> u64 {
        self.critic_version
    }

    /// `V(s)` and `H(s)` for every row of `obs` (rows × obs_dim), all of task `task`.
    pub fn evaluate(
        &mut self,
        obs: &[f32],
        task: usize,
        values: &mut [f64],
        entropies: &mut [f64],
    ) -> Result<(), SacError> {
        let (od, ad, nt) = (self.obs_dim, self.act_dim, self.num_tasks);
        let rows = values.len();
        if obs.len() != rows * od || entropies.len() != rows || task >= nt {
            return Err(SacError::Shape(format!(
                "evaluate: {} obs values, {rows} value and {} entropy slots, task {task} of {nt}",
                obs.len(),
                entropies.len()
            )));
        }
        for start in (0..rows).step_by(self.max_rows) {
            let n = (rows - start).min(self.max_rows);
            let chunk = &obs[start * od..(start + n) * od];
            {
                let input = self.policy_cache.input_mut(0..n);
                for (row, o) in input.chunks_exact_mut(od + nt).zip(chunk.chunks_exact(od)) {
                    row[..od].copy_from_slice(o);
                    row[od..].fill(0.0);
                    row[od + task] = 1.0;
                }
            }
            self.policy.forward(&mut self.policy_cache, n, Par::Seq);
            let head = self.policy_cache.output(0..n);
            for (r, h) in head.chunks_exact(2 * ad).enumerate() {
                let (mean, log_std) = h.split_at(ad);
                let clamped: Vec<f64> = log_std
                    .iter()
                    .map(|&l| f64::from(l).clamp(LOG_STD_MIN, LOG_STD_MAX))
                    .collect();
                let mean64: Vec<f64> = mean.iter().map(|&m| f64::from(m)).collect();
                entropies[start + r] = squashed_gaussian_entropy(&mean64, &clamped);
                for (a, &m) in self.actions[r * ad..(r + 1) * ad].iter_mut().zip(mean) {
                    *a = m.tanh();
                }
            }
            {
                let input = self.critic_cache.input_mut(0..n);
                for (r, (row, o)) in input
                    .chunks_exact_mut(od + nt + ad)
                    .zip(chunk.chunks_exact(od))
                    .enumerate()
                {
                    row[..od].copy_from_slice(o);
                    row[od..od + nt].fill(0.0);
                    row[od + task] = 1.0;
                    row[od + nt..].copy_from_slice(&self.actions[r * ad..(r + 1) * ad]);
                }
            }
            let out = &mut values[start..start + n];
            self.critics[0].forward(&mut self.critic_cache, n, Par::Seq);
            for (v, &q) in out.iter_mut().zip(self.critic_cache.output(0..n)) {
                *v = f64::from(q);
            }
            self.critics[1].forward(&mut self.critic_cache, n, Par::Seq);
            for (v, &q) in out.iter_mut().zip(self.critic_cache.output(0..n)) {
                *v = v.min(f64::from(q));
            }
        }
        Ok(())
    }
}
