//! The one configuration struct of MTSAC.

use crate::care::CareConfig;
use crate::error::SacError;
use serde::{Deserialize, Serialize};

/// Every hyper-parameter of multi-task SAC; a TOML file may set any subset.
///
/// Defaults follow the paper (τ = 0.005, γ = 0.99, lr 3e-4) and the Meta-World v3 reference
/// MTSAC (`rainx0r/metaworld-algorithms`, `examples/multi_task/mtsac_mt10.py` and its
/// `config/` files): 3 hidden layers of 400, He-uniform initialisation with zero biases and
/// small output heads (`config/nn.py`, `rl/networks.py`), Adam with ε = 1e-5
/// (`config/optim.py`), gradients clipped to a global norm of 1.0 on actor and critics. Each
/// field says which reference its default follows.
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
    /// Threads of the update (faer GEMMs and the twin critics run on a private rayon pool),
    /// 1 to [`MAX_THREADS`]. A run file may write `threads = "auto"`: the cores this process may
    /// use ([`auto_threads`]), counted when the file is read, so checkpoints record the count
    /// that ran (a thread count changes the GEMMs' summation order: a reproducible run is
    /// reproduced with the same count).
    #[serde(deserialize_with = "threads_or_auto")]
    pub threads: usize,
    /// Seed of network initialisation and of the update's sampling noise.
    pub seed: u64,
    /// Adam's ε for actor, critics and temperatures. Default 1e-5, the reference's
    /// (`config/optim.py`; PyTorch's own default is 1e-8).
    pub adam_eps: f64,
    /// Global-norm gradient clipping, applied separately to the policy's gradient and to the
    /// two critics' gradients together (one norm over both, as the reference's critic
    /// ensemble); the temperatures are not clipped. 0 turns clipping off. Default 1.0, the
    /// reference MT10 setting.
    pub max_grad_norm: f64,
    /// Initialisation of policy and critics. Default `"he_uniform"` (the reference:
    /// He-uniform hidden weights, zero hidden biases, heads in `±policy_head_init` and
    /// `±critic_head_init`); `"torch_default"` is PyTorch's `nn.Linear` (`±1/sqrt(fan_in)`).
    pub init: NetInit,
    /// Bound of the policy output layer's weights and biases under `init = "he_uniform"`.
    /// Default 1e-3 (reference: `uniform(1e-3)` policy head).
    pub policy_head_init: f64,
    /// Bound of each critic's output layer under `init = "he_uniform"`. Default 3e-3
    /// (reference: `uniform(3e-3)` Q head).
    pub critic_head_init: f64,
    /// CARE's context-based encoder in front of policy and critics (`[sac.care]`;
    /// `algorithm = "care"` sets it): the heads read `[mixture of state encoders, task
    /// encoding]` instead of `[observation, one-hot task id]`. `None`: MTSAC.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub care: Option<CareConfig>,
}

pub use crate::limits::{MAX_LAYERS, MAX_THREADS};

/// Most threads `threads = "auto"` gives an update: beyond this, the GEMMs of Meta-World-sized
/// networks (3×400, batch 1280 at most) stop getting faster.
pub const MAX_AUTO_THREADS: usize = 8;

/// The update threads `threads = "auto"` means: the cores this process may run on
/// (`std::thread::available_parallelism`, which honours CPU affinity and cgroup quotas), at
/// most [`MAX_AUTO_THREADS`]. The actors and the selector share those cores: actors are paced
/// by the learner's update-to-data ratio (at MT10's 0.1 updates per transition an actor needs
/// about a tenth of a core), so the learner takes them all and the scheduler shares them.
pub fn auto_threads() -> usize {
    std::thread::available_parallelism()
        .map_or(1, std::num::NonZeroUsize::get)
        .min(MAX_AUTO_THREADS)
}

/// Reads `threads` as a count or the string `"auto"` ([`auto_threads`]).
fn threads_or_auto<'de, D: serde::Deserializer<'de>>(d: D) -> Result<usize, D::Error> {
    struct Visitor;
    impl serde::de::Visitor<'_> for Visitor {
        type Value = usize;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a thread count (1 to 256) or \"auto\"")
        }
        fn visit_u64<E: serde::de::Error>(self, n: u64) -> Result<usize, E> {
            usize::try_from(n).map_err(|_| E::custom(format!("threads {n} is too large")))
        }
        fn visit_i64<E: serde::de::Error>(self, n: i64) -> Result<usize, E> {
            u64::try_from(n)
                .map_err(|_| E::custom(format!("threads {n} must be at least 1")))
                .and_then(|n| self.visit_u64(n))
        }
        fn visit_str<E: serde::de::Error>(self, w: &str) -> Result<usize, E> {
            if w == "auto" {
                Ok(auto_threads())
            } else {
                Err(E::custom(format!(
                    "threads must be a count or \"auto\", not \"{w}\""
                )))
            }
        }
    }
    d.deserialize_any(Visitor)
}

/// How [`SacConfig::init`] initialises the networks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NetInit {
    /// He-uniform hidden layers, zero biases, small uniform heads (the reference MTSAC).
    #[default]
    HeUniform,
    /// PyTorch's `nn.Linear` default for every layer.
    TorchDefault,
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
            adam_eps: 1e-5,
            max_grad_norm: 1.0,
            init: NetInit::HeUniform,
            policy_head_init: 1e-3,
            critic_head_init: 3e-3,
            care: None,
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

    /// Input size of the policy: observation plus one-hot task id, or with CARE the mixture
    /// and the task encoding ([`CareConfig::front_dim`]).
    pub fn policy_input(&self) -> usize {
        match &self.care {
            Some(care) => care.front_dim(),
            None => self.obs_dim + self.num_tasks,
        }
    }

    /// Input size of a critic: the policy's input ([`Self::policy_input`]), then the action.
    pub fn critic_input(&self) -> usize {
        self.policy_input() + self.act_dim
    }

    /// The target entropy in force.
    pub fn target_entropy(&self) -> f64 {
        self.target_entropy.unwrap_or(-(self.act_dim as f64))
    }

    /// The initialisation scheme of the policy (`critic = false`) or of a critic.
    pub fn init_for(&self, critic: bool) -> terl_nn::Init {
        match self.init {
            NetInit::TorchDefault => terl_nn::Init::TorchDefault,
            NetInit::HeUniform => terl_nn::Init::HeUniform {
                head_bound: if critic {
                    self.critic_head_init
                } else {
                    self.policy_head_init
                },
            },
        }
    }

    /// Adam settings for a learning rate `lr` with this config's ε.
    pub fn adam(&self, lr: f64) -> terl_nn::AdamConfig {
        terl_nn::AdamConfig {
            eps: self.adam_eps,
            ..terl_nn::AdamConfig::with_lr(lr)
        }
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
        if self.batch_size > crate::limits::MAX_BATCH {
            return bad(format!(
                "batch_size {} is above {}",
                self.batch_size,
                crate::limits::MAX_BATCH
            ));
        }
        if let Some(w) = [self.obs_dim, self.act_dim, self.num_tasks]
            .into_iter()
            .chain(self.policy_hidden.iter().copied())
            .chain(self.critic_hidden.iter().copied())
            .find(|&w| w > crate::limits::MAX_WIDTH)
        {
            return bad(format!(
                "a width of {w} (obs_dim, act_dim, num_tasks or a hidden layer) is above {}",
                crate::limits::MAX_WIDTH
            ));
        }
        if self.policy_hidden.len() > MAX_LAYERS || self.critic_hidden.len() > MAX_LAYERS {
            return bad(format!("networks have at most {MAX_LAYERS} hidden layers"));
        }
        if !(0.0..=1.0).contains(&self.gamma) || !(0.0..=1.0).contains(&self.tau) {
            return bad(format!(
                "gamma {} and tau {} must be in [0, 1]",
                self.gamma, self.tau
            ));
        }
        if !(1..=MAX_THREADS).contains(&self.threads) {
            return bad(format!(
                "threads {} must be 1 to {MAX_THREADS} (or \"auto\" in a run file)",
                self.threads
            ));
        }
        if !(self.adam_eps.is_finite() && self.adam_eps > 0.0) {
            return bad(format!("adam_eps {} must be > 0", self.adam_eps));
        }
        if !(self.max_grad_norm.is_finite() && self.max_grad_norm >= 0.0) {
            return bad(format!(
                "max_grad_norm {} must be ≥ 0 (0: no clipping)",
                self.max_grad_norm
            ));
        }
        if let Some(care) = &self.care {
            care.validate()?;
        }
        // Each network (with CARE, its encoder included; the critics carry their own) holds at
        // most tep::MAX_PARAMETERS: with its target and Adam moments that is ~1 GB of f32.
        let policy = crate::PolicySpec::from_config(self).checked_num_params();
        let critic = critic_spec_params(self);
        for (name, params) in [("policy", policy), ("critic", critic)] {
            if params.is_none_or(|p| p > crate::limits::MAX_PARAMETERS) {
                return bad(format!(
                    "the {name} network (policy_hidden {:?}, critic_hidden {:?}{}) has more than \
                     {} parameters: with its target and Adam moments it would not fit in memory",
                    self.policy_hidden,
                    self.critic_hidden,
                    if self.care.is_some() {
                        ", CARE encoder"
                    } else {
                        ""
                    },
                    crate::limits::MAX_PARAMETERS
                ));
            }
        }
        for (name, v) in [
            ("policy_head_init", self.policy_head_init),
            ("critic_head_init", self.critic_head_init),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{name} {v} must be ≥ 0"));
            }
        }
        Ok(())
    }
}

/// Parameters of one critic (its CARE encoder included), `None` on overflow.
fn critic_spec_params(cfg: &SacConfig) -> Option<usize> {
    let mut width = cfg.critic_input();
    let mut total = 0usize;
    for &h in &cfg.critic_hidden {
        total = total.checked_add(width.checked_mul(h)?.checked_add(h)?)?;
        width = h;
    }
    total = total.checked_add(width.checked_add(1)?)?;
    match &cfg.care {
        Some(c) => total.checked_add(c.policy_num_params(cfg.obs_dim, cfg.num_tasks)?),
        None => Some(total),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn threads_of(toml_text: &str) -> Result<usize, String> {
        let c: SacConfig = toml::from_str(toml_text).map_err(|e| e.to_string())?;
        c.validate().map_err(|e| e.to_string())?;
        Ok(c.threads)
    }

    #[test]
    fn threads_are_a_count_or_auto() {
        assert_eq!(threads_of("threads = 3"), Ok(3));
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        assert_eq!(
            threads_of("threads = \"auto\""),
            Ok(cores.min(MAX_AUTO_THREADS))
        );
        assert_eq!(threads_of(""), Ok(1), "the library default is one thread");
        for (bad, says) in [
            ("threads = 0", "must be 1 to 256"),
            ("threads = 257", "must be 1 to 256"),
            ("threads = -1", "must be at least 1"),
            ("threads = \"many\"", "not \"many\""),
            ("threads = 1.5", "a thread count"),
        ] {
            let e = threads_of(bad).unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    /// Sizes that would abort a process on allocation, or overflow f32 in CARE's attention,
    /// are configuration errors; the largest accepted settings still validate.
    #[test]
    fn network_sizes_and_care_temperature_are_bounded() {
        let base = || SacConfig {
            obs_dim: 39,
            act_dim: 4,
            num_tasks: 10,
            ..SacConfig::default()
        };
        let check = |c: SacConfig| c.validate().map_err(|e| e.to_string());
        assert!(check(base()).is_ok());
        let mut c = base();
        c.policy_hidden = vec![100_000_000];
        assert!(check(c).unwrap_err().contains("above 16384"));
        let mut c = base();
        c.critic_hidden = vec![crate::limits::MAX_WIDTH; 3];
        assert!(check(c).unwrap_err().contains("would not fit in memory"));
        let mut c = base();
        c.critic_hidden = vec![64; MAX_LAYERS + 1];
        assert!(check(c).unwrap_err().contains("hidden layers"));
        let mut c = base();
        c.batch_size = 100_000_000;
        assert!(check(c).unwrap_err().contains("batch_size"));
        // A 4096-wide pair of layers (16.8M parameters) is still a network one may train.
        let mut c = base();
        c.policy_hidden = vec![4096, 4096];
        assert!(check(c).is_ok());
        let care = |f: &dyn Fn(&mut crate::CareConfig)| {
            let mut cc = crate::CareConfig::default();
            f(&mut cc);
            check(SacConfig {
                care: Some(cc),
                ..base()
            })
        };
        assert!(care(&|_| {}).is_ok());
        for t in [1e-300, 1e-4, 1e4, f64::NAN] {
            assert!(
                care(&|c| c.temperature = t)
                    .unwrap_err()
                    .contains("temperature"),
                "{t}"
            );
        }
        assert!(care(&|c| c.temperature = 1e-3).is_ok());
        assert!(care(&|c| c.feature_dim = 100_000_000)
            .unwrap_err()
            .contains("feature_dim"));
        assert!(care(&|c| c.expert_hidden = vec![100_000])
            .unwrap_err()
            .contains("expert_hidden"));
        // 64 experts of 4096: each alone fits, together the encoder does not.
        assert!(care(&|c| {
            c.num_experts = 64;
            c.expert_hidden = vec![4096, 4096];
        })
        .unwrap_err()
        .contains("would not fit in memory"));
    }
}
