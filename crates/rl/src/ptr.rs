//! PTR sample selection (paper Sec. IV.A): GAE, per-transition priority, ranking across a pool
//! of trajectories, and the success-rate gate that starts selection for a task. Pure: values, entropies and episodes
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
//!   by the caller. The policy that acts is the tanh-squashed Gaussian `a = tanh(u)`, so the
//!   entropy is that of the squashed distribution, `E[−log π(a|s)]` including the tanh Jacobian
//!   ([`squashed_gaussian_entropy`], computed by quadrature rather than from the one action
//!   taken: no sampling noise, and guided steps, whose action came from the Action Network, get
//!   the policy's entropy too). [`gaussian_entropy`] (pre-tanh) stays for comparison: it ignores
//!   that a saturated mean (`|μ| ≫ 1`) makes the executed action nearly deterministic.
//! - Eq. 9 calls `P(i) = α·p_τ^i + (1 − α)·p_E(i)` with α = 0.6 the *sample* priority, so every
//!   transition gets `P = 0.6·mean(GAE of its trajectory) + 0.4·entropy(s_t)`. Transitions of one
//!   trajectory share the first term and are ordered among themselves by entropy. No
//!   normalisation of the two terms is mentioned, so none is applied.
//! - Ranking is **across trajectories** ([`PtrPool`]): a trajectory's mean GAE is one number, so
//!   ranking the transitions of a single episode (a 512-transition batch filled in arrival order
//!   holds about one 500-step Meta-World episode) would leave only the entropy term. Scored
//!   trajectories of a task collect in a pool of [`PtrConfig::pool_trajectories`]; when it is
//!   full, all its transitions are ranked by `P` together, the top
//!   [`PtrConfig::top_fraction`] (not given in the paper) is selected and the pool empties.
//! - "Optimization is performed per batch, with each consisting of 512 samples": the selection
//!   leaves the pool in batches of [`PtrConfig::batch_size`] drawn from the ranked pool, highest
//!   `P` first (the first batch holds the pool's 512 best transitions, the last may be short).
//! - "We initiate the sample selection process when the training task achieves a success rate
//!   of 85 %": [`SuccessGate`] opens per task when its rolling success rate reaches the threshold
//!   and, by default, stays open ("initiate").

use crate::error::SacError;
use crate::success::SuccessWindow;
use serde::{Deserialize, Serialize};

/// Hyper-parameters of PTR selection. Defaults follow the paper where it gives a value.
///
/// ```toml
/// gamma = 0.99
/// lambda = 0.95
/// gae_weight = 0.6
/// batch_size = 512
/// pool_trajectories = 10
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
    /// Transitions per selected batch drawn from a ranked pool (paper: 512).
    pub batch_size: usize,
    /// Trajectories of one task ranked against each other ([`PtrPool`]); not in the paper.
    /// Memory: each task's pool holds at most `pool_trajectories` episodes (≤ 500 transitions
    /// each in Meta-World), so about `pool_trajectories · 500 · 350 B` per task (1.75 MB at 10).
    /// Larger pools compare more trajectories but delay the first selection.
    pub pool_trajectories: usize,
    /// Fraction of a ranked pool's transitions that is selected, in (0, 1] (not in the paper;
    /// rounded up, at least one transition).
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
            pool_trajectories: 10,
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
        if self.batch_size == 0 || self.success_window == 0 || self.pool_trajectories == 0 {
            return bad(
                "ptr batch_size, pool_trajectories and success_window must be positive".into(),
            );
        }
        // Each is held in full (windows and pools are allocated at their size).
        const MAX_COUNT: usize = 100_000;
        if self.batch_size > MAX_COUNT
            || self.success_window > MAX_COUNT
            || self.pool_trajectories > MAX_COUNT
        {
            return bad(format!(
                "ptr batch_size, pool_trajectories and success_window must be at most {MAX_COUNT}"
            ));
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

    /// Number of transitions selected from a ranked pool of `n`: `ceil(top_fraction · n)`, at
    /// least 1 (0 for an empty pool).
    pub fn selected_of(&self, n: usize) -> usize {
        ((self.top_fraction * n as f64).ceil() as usize).clamp(n.min(1), n)
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
    Truncated {
        /// The critic's `V(s_T)` of the state after the last step.
        last_value: f64,
    },
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
/// `Σ_j (½·ln(2πe) + log_std_j)`, in nats. Not what PTR uses (see
/// [`squashed_gaussian_entropy`]).
pub fn gaussian_entropy(log_std: &[f64]) -> f64 {
    let c = 0.5 * (2.0 * std::f64::consts::PI * std::f64::consts::E).ln();
    log_std.iter().map(|&l| c + l).sum()
}

/// Nodes and weights of 32-point Gauss–Hermite quadrature for the standard normal:
/// `E[f(ε)] ≈ Σ_i w_i f(z_i)`, `ε ~ N(0, 1)` (exact for polynomials up to degree 63).
/// Computed once (Newton iteration on the normalised Hermite recurrence).
fn normal_quadrature() -> &'static [(f64, f64)] {
    static NODES: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    NODES.get_or_init(|| {
        const N: usize = 32;
        let pim4 = std::f64::consts::PI.powf(-0.25);
        let (mut x, mut w) = ([0.0f64; N], [0.0f64; N]);
        let nf = N as f64;
        let mut z = 0.0f64;
        for i in 0..N.div_ceil(2) {
            z = match i {
                0 => (2.0 * nf + 1.0).sqrt() - 1.85575 * (2.0 * nf + 1.0).powf(-0.16667),
                1 => z - 1.14 * nf.powf(0.426) / z,
                2 => 1.86 * z - 0.86 * x[0],
                3 => 1.91 * z - 0.91 * x[1],
                _ => 2.0 * z - x[i - 2],
            };
            let mut pp = 1.0;
            for _ in 0..100 {
                // Orthonormal Hermite polynomials (weight e^{−x²}) at z.
                let (mut p1, mut p2) = (pim4, 0.0f64);
                for j in 0..N {
                    let p3 = p2;
                    p2 = p1;
                    let jf = j as f64;
                    p1 = z * (2.0 / (jf + 1.0)).sqrt() * p2 - (jf / (jf + 1.0)).sqrt() * p3;
                }
                pp = (2.0 * nf).sqrt() * p2;
                let step = p1 / pp;
                z -= step;
                if step.abs() < 1e-15 {
                    break;
                }
            }
            x[i] = z;
            x[N - 1 - i] = -z;
            w[i] = 2.0 / (pp * pp);
            w[N - 1 - i] = w[i];
        }
        // ∫ e^{−x²} f(x) dx → E[f(ε)] with ε = √2·x.
        let norm = std::f64::consts::PI.sqrt();
        x.iter()
            .zip(&w)
            .map(|(&x, &w)| (std::f64::consts::SQRT_2 * x, w / norm))
            .collect()
    })
}

/// `ln(1 − tanh²x) = 2·(ln 2 − x − softplus(−2x))` without cancellation.
fn log_one_minus_tanh2(x: f64) -> f64 {
    use terl_nn::Float;
    2.0 * (std::f64::consts::LN_2 - x - (-2.0 * x).softplus())
}

/// Entropy (nats) of the tanh-squashed diagonal Gaussian policy that acts, `a = tanh(u)`,
/// `u ~ N(mean, exp(log_std)²)`: `H = E[−log π(a|s)]`, with the change of variables
/// `log π(a|s) = log N(u; μ, σ) − Σ_j ln(1 − tanh² u_j)`, so per dimension
/// `H_j = ½·ln(2πe) + log σ_j + E_ε[ln(1 − tanh²(μ_j + σ_j·ε))]`. The expectation is a 32-point
/// Gauss–Hermite quadrature: deterministic (equal states give equal priorities) and within
/// about 1e-3 of a large Monte-Carlo estimate of `−log π(a|s)` over `log_std ∈ [−20, 2]`.
/// Always ≤ [`gaussian_entropy`] (the Jacobian term is ≤ 0); it falls as `|μ|` saturates.
///
/// # Panics
/// If `mean` and `log_std` differ in length.
pub fn squashed_gaussian_entropy(mean: &[f64], log_std: &[f64]) -> f64 {
    assert_eq!(mean.len(), log_std.len(), "one log-std per mean");
    let q = normal_quadrature();
    let jacobian: f64 = mean
        .iter()
        .zip(log_std)
        .map(|(&m, &l)| {
            let sd = l.exp();
            q.iter()
                .map(|&(z, w)| w * log_one_minus_tanh2(m + sd * z))
                .sum::<f64>()
        })
        .sum();
    gaussian_entropy(log_std) + jacobian
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

/// A pool of scored trajectories ranked against each other (Eq. 9 across trajectories; see the
/// module docs). Items are transitions (or handles to them) with their priority `P`; one call of
/// [`PtrPool::push_trajectory`] adds one trajectory's items. When the pool holds
/// [`PtrConfig::pool_trajectories`] trajectories, all its items are ranked by `P`, the top
/// [`PtrConfig::selected_of`] of them are returned in batches of [`PtrConfig::batch_size`]
/// (highest `P` first; NaN last, ties in arrival order), and the pool empties. Memory is bounded
/// by `pool_trajectories` trajectories.
#[derive(Clone, Debug)]
pub struct PtrPool<I> {
    cfg: PtrConfig,
    items: Vec<(f64, I)>,
    trajectories: usize,
    rankings: u64,
    seen: u64,
    selected: u64,
}

impl<I> PtrPool<I> {
    /// An empty pool ranking by `cfg` (its `pool_trajectories`, `top_fraction` and `batch_size`).
    pub fn new(cfg: &PtrConfig) -> Self {
        Self {
            cfg: cfg.clone(),
            items: Vec::new(),
            trajectories: 0,
            rankings: 0,
            seen: 0,
            selected: 0,
        }
    }

    /// Adds one trajectory's `(priority, item)` pairs; when this fills the pool, returns its
    /// selection as batches (see the type docs), otherwise nothing. An empty trajectory is
    /// not counted.
    pub fn push_trajectory(
        &mut self,
        items: impl IntoIterator<Item = (f64, I)>,
    ) -> Vec<Vec<(f64, I)>> {
        let before = self.items.len();
        self.items.extend(items);
        let added = self.items.len() - before;
        if added == 0 {
            return Vec::new();
        }
        self.seen += added as u64;
        self.trajectories += 1;
        if self.trajectories >= self.cfg.pool_trajectories {
            self.rank()
        } else {
            Vec::new()
        }
    }

    /// Ranks a partly filled pool now (end of a run), selecting the same fraction of it.
    pub fn flush(&mut self) -> Vec<Vec<(f64, I)>> {
        if self.items.is_empty() {
            return Vec::new();
        }
        self.rank()
    }

    fn rank(&mut self) -> Vec<Vec<(f64, I)>> {
        let keep = self.cfg.selected_of(self.items.len());
        let prios: Vec<f64> = self.items.iter().map(|(p, _)| *p).collect();
        let order = top_k(&prios, keep);
        let mut slots: Vec<Option<(f64, I)>> = self.items.drain(..).map(Some).collect();
        let mut ranked = order
            .into_iter()
            .map(|i| slots[i].take().expect("top_k indices are distinct"));
        let mut out = Vec::with_capacity(keep.div_ceil(self.cfg.batch_size));
        loop {
            let batch: Vec<(f64, I)> = ranked.by_ref().take(self.cfg.batch_size).collect();
            if batch.is_empty() {
                break;
            }
            out.push(batch);
        }
        self.trajectories = 0;
        self.rankings += 1;
        self.selected += keep as u64;
        out
    }

    /// Trajectories and transitions waiting for the pool to fill.
    pub fn pending(&self) -> (usize, usize) {
        (self.trajectories, self.items.len())
    }

    /// Pools ranked, items seen, items selected so far.
    pub fn counts(&self) -> (u64, u64, u64) {
        (self.rankings, self.seen, self.selected)
    }
}

/// Per-task rolling success rate and the gate that starts selection (Sec. IV.A, 85 %).
#[derive(Clone, Debug)]
pub struct SuccessGate {
    threshold: f64,
    min_episodes: usize,
    latch: bool,
    tasks: Vec<TaskGate>,
}

#[derive(Clone, Debug)]
struct TaskGate {
    recent: SuccessWindow,
    episodes: u64,
    opened: bool,
}

impl SuccessGate {
    /// A gate for `num_tasks` tasks, all closed, each over a [`SuccessWindow`] of
    /// `cfg.success_window` episodes; a task opens once it has at least `cfg.min_episodes` episodes
    /// (default: the window length) and a rate of at least `cfg.success_threshold`.
    pub fn new(cfg: &PtrConfig, num_tasks: usize) -> Self {
        Self {
            threshold: cfg.success_threshold,
            min_episodes: cfg.min_episodes.unwrap_or(cfg.success_window),
            latch: cfg.latch,
            tasks: vec![
                TaskGate {
                    recent: SuccessWindow::new(cfg.success_window),
                    episodes: 0,
                    opened: false,
                };
                num_tasks
            ],
        }
    }

    /// Records one finished training episode of `task`; returns whether the gate is open after
    /// it.
    pub fn record(&mut self, task: usize, success: bool) -> bool {
        let (min, thr, latch) = (self.min_episodes, self.threshold, self.latch);
        let g = &mut self.tasks[task];
        g.recent.push(success);
        g.episodes += 1;
        let rate = g.recent.rate();
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
        self.tasks[task].recent.rate()
    }

    /// Episodes recorded for `task`.
    pub fn episodes(&self, task: usize) -> u64 {
        self.tasks[task].episodes
    }
}
