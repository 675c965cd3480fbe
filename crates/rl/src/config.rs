//! The one configuration struct of MTSAC.

use crate::error::SacError;
use serde::{Deserialize, Serialize};

/// Every hyper-parameter of multi-task SAC. Defaults follow the paper and Meta-World's reference
/// MTSAC (3 hidden layers of 400, τ = 0.005, γ = 0.99, lr 3e-4); a TOML file may set any subset.
///
/// ```toml
/// obs_dim = 39
/// act_dim = 4
/// num_tasks = 10
/// policy_hidden = [400, 400, 400]
/// critic_hidden = [400, 400, 400]
/// batch_size = 1280
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SacConfig {
    /// Environment observation size, without the one-hot task id (39 for Meta-World).
    pub obs_dim: usize,
    /// Action size; actions are in `[-1, 1]` (4 for Meta-World).
    pub act_dim: usize,
    /// Number of tasks; the one-hot task id of this size is appended to every observation.
    pub num_tasks: usize,
    /// Hidden layer widths of the policy (ReLU).
    pub policy_hidden: Vec<usize>,
    /// Hidden layer widths of each of the twin Q critics (ReLU).
    pub critic_hidden: Vec<usize>,
    /// Discount factor γ.
    pub gamma: f64,
    /// Polyak factor τ of the target critics (`target ← (1 − τ)·target + τ·critic`).
    pub tau: f64,
    /// Adam learning rate of the policy.
    pub actor_lr: f64,
    /// Adam learning rate of both critics.
    pub critic_lr: f64,
    /// Adam learning rate of the per-task log temperatures.
    pub alpha_lr: f64,
    /// Initial `ln α` of every task.
    pub initial_log_alpha: f64,
    /// Target entropy; `None` means `−act_dim`.
    pub target_entropy: Option<f64>,
    /// Transitions per update, drawn evenly across tasks.
    pub batch_size: usize,
    /// Threads of the update (faer GEMMs and the twin critics run on a private rayon pool).
    pub threads: usize,
    /// Seed of network initialisation and of the update's sampling noise.
    pub seed: u64,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            obs_dim: 39,
            act_dim: 4,
            num_tasks: 1,
            policy_hidden: vec![400, 400, 400],
            critic_hidden: vec![400, 400, 400],
            gamma: 0.99,
            tau: 0.005,
            actor_lr: 3e-4,
            critic_lr: 3e-4,
            alpha_lr: 3e-4,
            initial_log_alpha: 0.0,
            target_entropy: None,
            batch_size: 1280,
            threads: 1,
            seed: 0,
        }
    }
}

impl SacConfig {
    /// Parses a TOML document (unknown keys are an error).
    pub fn from_toml(text: &str) -> Result<Self, SacError> {
        let cfg: Self = toml::from_str(text).map_err(|e| SacError::Config(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("SacConfig serialises to TOML")
    }

    /// Input size of the policy: observation plus one-hot task id.
    pub fn policy_input(&self) -> usize {
        self.obs_dim + self.num_tasks
    }

    /// Input size of a critic: observation, one-hot task id, action.
    pub fn critic_input(&self) -> usize {
        self.obs_dim + self.num_tasks + self.act_dim
    }

    /// The target entropy in force.
    pub fn target_entropy(&self) -> f64 {
        self.target_entropy.unwrap_or(-(self.act_dim as f64))
    }

    /// Checks sizes and ranges.
    pub fn validate(&self) -> Result<(), SacError> {
        let bad = |m: String| Err(SacError::Config(m));
        if self.obs_dim == 0 || self.act_dim == 0 || self.num_tasks == 0 {
            return bad("obs_dim, act_dim and num_tasks must be positive".into());
        }
        if self.batch_size == 0 {
            return bad("batch_size must be positive".into());
        }
        if self.policy_hidden.contains(&0) || self.critic_hidden.contains(&0) {
            return bad("hidden layer widths must be positive".into());
        }
        if !(0.0..=1.0).contains(&self.gamma) || !(0.0..=1.0).contains(&self.tau) {
            return bad(format!(
                "gamma {} and tau {} must be in [0, 1]",
                self.gamma, self.tau
            ));
        }
        if self.threads == 0 {
            return bad("threads must be at least 1".into());
        }
        Ok(())
    }
}
