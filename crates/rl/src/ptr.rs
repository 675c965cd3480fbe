//! PTR sample selection (paper Sec. IV.A): GAE, per-transition priority, ranking in batches, and
//! the success-rate gate that starts selection for a task. Pure: values, entropies and episodes
//! come from the caller (the selector service), selected items go back to it.
//!
//! # Reading of Sec. IV.A
//!
//! - Eq. 6–7: `δ_t = r_t + γ·V(s_{t+1}) − V(s_t)`, `A_j = Σ_{l=0}^{T−j−1} (γλ)^l δ_{j+l}`, with
//!   γ = 0.99, λ = 0.95. The paper writes the sum up to the trajectory's end; we bootstrap the
//!   last δ with `V(s_T)` when the episode was cut by the time limit and use `V(s_T) = 0` when it
//!   terminated (the usual GAE convention; Meta-World episodes are truncated at 500 steps).
//! - Eq. 5: `p_τ^i = mean{[A_j]_τ^i}` is a **trajectory** quantity: the mean GAE over all steps
//!   of trajectory `τ_i`.
//! - Eq. 8: `p_E(i) = −∫ π(a|s) log π(a|s) da` (the paper's `p(s|a)` is read as the policy
//!   density) is the policy entropy at the sample's state, a **per-transition** quantity supplied
//!   by the caller (for example [`gaussian_entropy`] of the policy head, or `−log π(a|s)`).
//! - Eq. 9 calls `P(i) = α·p_τ^i + (1 − α)·p_E(i)` with α = 0.6 the *sample* priority, so every
//!   transition gets `P = 0.6·mean(GAE of its trajectory) + 0.4·entropy(s_t)`. Transitions of one
//!   trajectory share the first term and are ordered among themselves by entropy. No
//!   normalisation of the two terms is mentioned, so none is applied.
//! - "Optimization is performed per batch, with each consisting of 512 samples": transitions of
//!   gated tasks are collected in arrival order into batches of 512 ([`PtrBatcher`]); each full
//!   batch is ranked by `P` and its top fraction ([`PtrConfig::top_fraction`], not given in the
//!   paper) is selected, the rest dropped.
//! - "We initiate the sample selection process when the training task achieves a success rate
//!   of 85 %": [`SuccessGate`] opens per task when its rolling success rate reaches the threshold
//!   and, by default, stays open ("initiate").

use crate::error::SacError;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Hyper-parameters of PTR selection. Defaults follow the paper where it gives a value.
///
/// ```toml
/// gamma = 0.99
/// lambda = 0.95
/// gae_weight = 0.6
/// batch_size = 512
/// top_fraction = 0.25
/// success_threshold = 0.85
/// success_window = 50
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PtrConfig {
    /// Discount γ of the TD errors (paper: 0.99).
    pub gamma: f64,
    /// GAE λ (paper: 0.95).
    pub lambda: f64,
    /// Weight α of the mean-GAE term; the entropy gets `1 − α` (paper: 0.6).
    pub gae_weight: f64,
    /// Transitions per ranking batch (paper: 512).
    pub batch_size: usize,
    /// Fraction of each batch that is selected, in (0, 1] (not in the paper; rounded up, at
    /// least one transition).
    pub top_fraction: f64,
    /// Rolling success rate at which a task's selection starts (paper: 0.85). 0 opens the gate
    /// once `min_episodes` episodes are recorded (for smoke runs).
    pub success_threshold: f64,
    /// Episodes in the rolling success window of each task.
    pub success_window: usize,
    /// Episodes a task must have finished before its gate can open (defaults to the window).
    pub min_episodes: Option<usize>,
    /// Whether an open gate stays open when the success rate drops again (the paper "initiates"
    /// selection, so true by default).
    pub latch: bool,
}

impl Default for PtrConfig {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            lambda: 0.95,
            gae_weight: 0.6,
            batch_size: 512,
            top_fraction: 0.25,
            success_threshold: 0.85,
            success_window: 50,
            min_episodes: None,
            latch: true,
        }
    }
}

impl PtrConfig {
    /// Parses a TOML document (unknown keys are an error).
    pub fn from_toml(text: &str) -> Result<Self, SacError> {
        let cfg: Self = toml::from_str(text).map_err(|e| SacError::Config(e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks ranges.
    pub fn validate(&self) -> Result<(), SacError> {
        let bad = |m: String| Err(SacError::Config(m));
        if !(0.0..=1.0).contains(&self.gamma) || !(0.0..=1.0).contains(&self.lambda) {
            return bad(format!(
                "ptr gamma {} and lambda {} must be in [0, 1]",
                self.gamma, self.lambda
            ));
        }
        if !(0.0..=1.0).contains(&self.gae_weight) {
            return bad(format!("ptr gae_weight {} not in [0, 1]", self.gae_weight));
        }
        if self.batch_size == 0 || self.success_window == 0 {
            return bad("ptr batch_size and success_window must be positive".into());
        }
        if !(self.top_fraction > 0.0 && self.top_fraction <= 1.0) {
            return bad(format!(
                "ptr top_fraction {} not in (0, 1]",
                self.top_fraction
            ));
        }
        if !(0.0..=1.0).contains(&self.success_threshold) {
            return bad(format!(
                "ptr success_threshold {} not in [0, 1]",
                self.success_threshold
            ));
        }
        Ok(())
    }

    /// Number of transitions selected from a full batch: `ceil(top_fraction · batch_size)`.
    pub fn selected_per_batch(&self) -> usize {
        ((self.top_fraction * self.batch_size as f64).ceil() as usize).clamp(1, self.batch_size)
    }

    /// Priority of one transition (Eq. 9).
    pub fn priority(&self, mean_gae: f64, entropy: f64) -> f64 {
        self.gae_weight * mean_gae + (1.0 - self.gae_weight) * entropy
    }
}

/// How a trajectory ended, which decides the value after its last step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TrajectoryEnd {
    /// A true terminal state: `V(s_T) = 0`.
    Terminated,
    /// Cut by a time limit (or still running): bootstrap with the critic's `V(s_T)`.
    Truncated { last_value: f64 },
}

/// GAE over one trajectory (Eq. 6–7) into `out`: `rewards[t] = r_t`, `values[t] = V(s_t)` for
/// `t < T`, the value after the last step from `end`. Computed backwards,
/// `A_t = δ_t + γλ·A_{t+1}`.
pub fn gae_into(
    rewards: &[f64],
    values: &[f64],
    end: TrajectoryEnd,
    gamma: f64,
    lambda: f64,
    out: &mut [f64],
) {
    let n = rewards.len();
    assert_eq!(values.len(), n, "one value per reward");
    assert_eq!(out.len(), n, "one output per reward");
    let mut next_value = match end {
        TrajectoryEnd::Terminated => 0.0,
        TrajectoryEnd::Truncated { last_value } => last_value,
    };
    let mut acc = 0.0;
    for t in (0..n).rev() {
        let delta = rewards[t] + gamma * next_value - values[t];
        acc = delta + gamma * lambda * acc;
        out[t] = acc;
        next_value = values[t];
    }
}

/// [`gae_into`] returning a new vector.
pub fn gae(
    rewards: &[f64],
    values: &[f64],
    end: TrajectoryEnd,
    gamma: f64,
    lambda: f64,
) -> Vec<f64> {
    let mut out = vec![0.0; rewards.len()];
    gae_into(rewards, values, end, gamma, lambda, &mut out);
    out
}

/// Differential entropy of the *pre-tanh* diagonal Gaussian with these log standard deviations:
/// `Σ_j (½·ln(2πe) + log_std_j)`. A cheap per-state entropy input for [`trajectory_priorities`]
/// (the tanh squashing changes it by `E[Σ ln(1 − tanh²u)]`, which needs samples; `−log π(a|s)`
/// of the taken action is the sampled alternative).
pub fn gaussian_entropy(log_std: &[f64]) -> f64 {
    let c = 0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E).ln();
    log_std.iter().map(|&l| c + l).sum()
}

/// Per-transition priorities of one trajectory (Eq. 5–9): `P_t = α·mean(A) + (1 − α)·H_t`.
/// Returns the priorities and the trajectory's mean GAE.
pub fn trajectory_priorities(
    cfg: &PtrConfig,
    rewards: &[f64],
    values: &[f64],
    end: TrajectoryEnd,
    entropies: &[f64],
) -> (Vec<f64>, f64) {
    assert_eq!(entropies.len(), rewards.len(), "one entropy per transition");
    if rewards.is_empty() {
        return (Vec::new(), 0.0);
    }
    let adv = gae(rewards, values, end, cfg.gamma, cfg.lambda);
    let mean = adv.iter().sum::<f64>() / adv.len() as f64;
    let p = entropies.iter().map(|&h| cfg.priority(mean, h)).collect();
    (p, mean)
}

/// Indices of the `k` largest priorities, highest first (ties keep the earlier index first;
/// NaN priorities rank last).
pub fn top_k(priorities: &[f64], k: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..priorities.len()).collect();
    idx.sort_by(|&a, &b| {
        let (pa, pb) = (priorities[a], priorities[b]);
        match (pa.is_nan(), pb.is_nan()) {
            (true, true) => a.cmp(&b),
            (true, false) => std::cmp::Ordering::Greater,
            (false, true) => std::cmp::Ordering::Less,
            (false, false) => pb.total_cmp(&pa).then(a.cmp(&b)),
        }
    });
    idx.truncate(k.min(priorities.len()));
    idx
}

/// Collects scored items (transitions, or handles to them) into batches of
/// [`PtrConfig::batch_size`]; every full batch is ranked and its top
/// [`PtrConfig::selected_per_batch`] items are returned, highest priority first.
#[derive(Clone, Debug)]
pub struct PtrBatcher<I> {
    batch_size: usize,
    keep: usize,
    pending: Vec<(f64, I)>,
    batches: u64,
    seen: u64,
    selected: u64,
}

impl<I> PtrBatcher<I> {
    pub fn new(cfg: &PtrConfig) -> Self {
        Self {
            batch_size: cfg.batch_size,
            keep: cfg.selected_per_batch(),
            pending: Vec::with_capacity(cfg.batch_size),
            batches: 0,
            seen: 0,
            selected: 0,
        }
    }

    /// Adds one item with its priority; when this fills a batch, returns the batch's selection.
    pub fn push(&mut self, priority: f64, item: I) -> Option<Vec<(f64, I)>> {
        self.pending.push((priority, item));
        self.seen += 1;
        (self.pending.len() == self.batch_size).then(|| self.rank_pending())
    }

    /// Adds many items; returns the selections of all batches they completed, concatenated.
    pub fn extend(&mut self, items: impl IntoIterator<Item = (f64, I)>) -> Vec<(f64, I)> {
        let mut out = Vec::new();
        for (p, item) in items {
            if let Some(sel) = self.push(p, item) {
                out.extend(sel);
            }
        }
        out
    }

    /// Ranks a partial batch now (end of a run), selecting the same fraction of it.
    pub fn flush(&mut self) -> Vec<(f64, I)> {
        if self.pending.is_empty() {
            return Vec::new();
        }
        self.rank_pending()
    }

    fn rank_pending(&mut self) -> Vec<(f64, I)> {
        let n = self.pending.len();
        let keep = if n == self.batch_size {
            self.keep
        } else {
            ((self.keep as f64 * n as f64 / self.batch_size as f64).ceil() as usize).clamp(1, n)
        };
        let prios: Vec<f64> = self.pending.iter().map(|(p, _)| *p).collect();
        let order = top_k(&prios, keep);
        let mut slots: Vec<Option<(f64, I)>> = self.pending.drain(..).map(Some).collect();
        let out: Vec<(f64, I)> = order
            .into_iter()
            .map(|i| slots[i].take().expect("top_k indices are distinct"))
            .collect();
        self.batches += 1;
        self.selected += out.len() as u64;
        out
    }

    /// Items waiting for their batch to fill.
    pub fn pending(&self) -> usize {
        self.pending.len()
    }

    /// Batches ranked, items seen, items selected so far.
    pub fn counts(&self) -> (u64, u64, u64) {
        (self.batches, self.seen, self.selected)
    }
}

/// Per-task rolling success rate and the gate that starts selection (Sec. IV.A, 85 %).
#[derive(Clone, Debug)]
pub struct SuccessGate {
    threshold: f64,
    window: usize,
    min_episodes: usize,
    latch: bool,
    tasks: Vec<TaskGate>,
}

#[derive(Clone, Debug, Default)]
struct TaskGate {
    recent: VecDeque<bool>,
    successes: usize,
    episodes: u64,
    opened: bool,
}

impl SuccessGate {
    pub fn new(cfg: &PtrConfig, num_tasks: usize) -> Self {
        Self {
            threshold: cfg.success_threshold,
            window: cfg.success_window,
            min_episodes: cfg.min_episodes.unwrap_or(cfg.success_window),
            latch: cfg.latch,
            tasks: vec![TaskGate::default(); num_tasks],
        }
    }

    /// Records one finished training episode of `task`; returns whether the gate is open after
    /// it.
    pub fn record(&mut self, task: usize, success: bool) -> bool {
        let (window, min, thr, latch) =
            (self.window, self.min_episodes, self.threshold, self.latch);
        let g = &mut self.tasks[task];
        g.recent.push_back(success);
        g.successes += success as usize;
        if g.recent.len() > window {
            let old = g.recent.pop_front().expect("window is not empty");
            g.successes -= old as usize;
        }
        g.episodes += 1;
        let rate = g.successes as f64 / g.recent.len() as f64;
        let now = g.episodes >= min as u64 && rate >= thr;
        g.opened = if latch { g.opened || now } else { now };
        g.opened
    }

    /// Whether `task`'s trajectories are scored and selected.
    pub fn is_open(&self, task: usize) -> bool {
        self.tasks[task].opened
    }

    /// Rolling success rate of `task` (0 before any episode).
    pub fn success_rate(&self, task: usize) -> f64 {
        let g = &self.tasks[task];
        if g.recent.is_empty() {
            0.0
        } else {
            g.successes as f64 / g.recent.len() as f64
        }
    }

    /// Episodes recorded for `task`.
    pub fn episodes(&self, task: usize) -> u64 {
        self.tasks[task].episodes
    }
}
