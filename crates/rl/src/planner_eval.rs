//! Offline checks of the planner (`terl planner eval`, and the learner's guidance gate): how well
//! the reachability net F orders and counts the steps between two states of a held-out
//! trajectory.
//!
//! Pairs `(s_t, s_{t+k})` are taken from the part of a trajectory up to its first success (after
//! it the state stops changing in a way the step count can follow: a trajectory that holds the
//! object at the goal for 400 steps has pairs 400 steps apart that are one step apart in truth).
//! The true distance is unknown; the step gap `k` along a scripted or selected trajectory is an
//! upper bound of it and, for near-optimal trajectories, close to it. Two scores:
//!
//! - **Spearman ρ** between F and `k` (rank correlation, ties at their mean rank), overall and
//!   per task: does F order goals by how far they are?
//! - **Median relative error** `|F − k| / k` in bins of `k` ([`GAP_BINS`]): does F count steps?

use crate::tep::Tep;
use faer::Par;
use rand::Rng;
use serde::Serialize;
use terl_nn::MlpCache;

/// Rows per forward pass of [`predict_gaps`].
const PREDICT_ROWS: usize = 1024;

/// `F(s_i, g_i, a_i)` in steps (the output scale applied) for every pair, through F's batch
/// forward pass (`PREDICT_ROWS` rows at a time).
pub fn predict_gaps(tep: &Tep<f32>, pairs: &PairSet, par: Par) -> Vec<f64> {
    let (od, ad) = (pairs.obs_dim, pairs.act_dim);
    let cfg = tep.config();
    assert_eq!(
        (od, ad),
        (cfg.obs_dim, cfg.act_dim),
        "pairs of other dimensions"
    );
    let w = cfg.f_input();
    let f = tep.f_net();
    let mut cache = MlpCache::new(f, PREDICT_ROWS);
    let mut out = Vec::with_capacity(pairs.len());
    let c = cfg.f_output_scale;
    for start in (0..pairs.len()).step_by(PREDICT_ROWS) {
        let n = PREDICT_ROWS.min(pairs.len() - start);
        let x = cache.input_mut(0..n);
        for r in 0..n {
            let i = start + r;
            let row = &mut x[r * w..(r + 1) * w];
            row[..od].copy_from_slice(&pairs.obs[i * od..(i + 1) * od]);
            row[od..2 * od].copy_from_slice(&pairs.goals[i * od..(i + 1) * od]);
            row[2 * od..].copy_from_slice(&pairs.actions[i * ad..(i + 1) * ad]);
        }
        f.forward(&mut cache, n, par);
        out.extend(cache.output(0..n).iter().map(|&y| c * f64::from(y)));
    }
    out
}

/// Bins of the true gap `k` (inclusive bounds) for the relative error: 1–10, 11–30, 31–100 and
/// beyond 100 steps.
pub const GAP_BINS: [(u32, u32); 4] = [(1, 10), (11, 30), (31, 100), (101, u32::MAX)];

/// Ranks of `v` from 1, ties at the mean of their ranks (the rank transform of Spearman's ρ).
pub fn ranks(v: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..v.len()).collect();
    order.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    let mut r = vec![0.0; v.len()];
    let mut i = 0;
    while i < order.len() {
        let mut j = i;
        while j + 1 < order.len() && v[order[j + 1]] == v[order[i]] {
            j += 1;
        }
        let mean = (i + j) as f64 / 2.0 + 1.0;
        for &k in &order[i..=j] {
            r[k] = mean;
        }
        i = j + 1;
    }
    r
}

/// Pearson correlation of `x` and `y` (NaN for fewer than two values or zero variance).
pub fn pearson(x: &[f64], y: &[f64]) -> f64 {
    assert_eq!(x.len(), y.len(), "pearson: lengths differ");
    let n = x.len() as f64;
    if x.len() < 2 {
        return f64::NAN;
    }
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        sxy += (a - mx) * (b - my);
        sxx += (a - mx).powi(2);
        syy += (b - my).powi(2);
    }
    if sxx == 0.0 || syy == 0.0 {
        return f64::NAN;
    }
    sxy / (sxx * syy).sqrt()
}

/// Spearman's rank correlation: Pearson's on [`ranks`] (NaN when undefined).
pub fn spearman(x: &[f64], y: &[f64]) -> f64 {
    pearson(&ranks(x), &ranks(y))
}

/// Median of `v` (mean of the two middle values for an even count; NaN when empty).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        (s[m - 1] + s[m]) / 2.0
    }
}

/// The relative error of one bin of [`GAP_BINS`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BinScore {
    /// Smallest gap `k` of the bin (inclusive).
    pub lo: u32,
    /// Largest gap `k` of the bin (inclusive).
    pub hi: u32,
    /// Pairs in the bin.
    pub pairs: usize,
    /// Median `|F − k| / k` (NaN without pairs).
    pub median_relative_error: f64,
    /// Median `F / k` (below 1: F underestimates).
    pub median_ratio: f64,
}

/// Scores of F on a set of pairs.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReachScore {
    /// Pairs scored, over all bins.
    pub pairs: usize,
    /// Spearman ρ between F and `k`.
    pub spearman: f64,
    /// Relative error per bin of [`GAP_BINS`], in that order.
    pub bins: Vec<BinScore>,
}

/// Scores predictions `pred[i] ≈ gaps[i]` (see the module docs).
pub fn score(pred: &[f64], gaps: &[u32]) -> ReachScore {
    assert_eq!(pred.len(), gaps.len(), "score: lengths differ");
    let k: Vec<f64> = gaps.iter().map(|&g| f64::from(g)).collect();
    let bins = GAP_BINS
        .iter()
        .map(|&(lo, hi)| {
            let (rel, ratio): (Vec<f64>, Vec<f64>) = pred
                .iter()
                .zip(gaps)
                .filter(|(_, &g)| (lo..=hi).contains(&g))
                .map(|(&p, &g)| {
                    let g = f64::from(g);
                    ((p - g).abs() / g, p / g)
                })
                .unzip();
            BinScore {
                lo,
                hi,
                pairs: rel.len(),
                median_relative_error: median(&rel),
                median_ratio: median(&ratio),
            }
        })
        .collect();
    ReachScore {
        pairs: pred.len(),
        spearman: spearman(pred, &k),
        bins,
    }
}

/// Evaluation pairs `(s_t, s_{t+k}, a_t)` with their task and gap, row-major `f32`.
#[derive(Clone, Debug, Default)]
pub struct PairSet {
    /// Observation length of `obs` and `goals` rows.
    pub obs_dim: usize,
    /// Action length of `actions` rows.
    pub act_dim: usize,
    /// Task index of each pair.
    pub tasks: Vec<usize>,
    /// Start states `s_t`, `[len, obs_dim]` row-major.
    pub obs: Vec<f32>,
    /// Goal states `s_{t+k}` of the same trajectory, `[len, obs_dim]` row-major.
    pub goals: Vec<f32>,
    /// Actions `a_t` taken at `s_t`, `[len, act_dim]` row-major.
    pub actions: Vec<f32>,
    /// True step gaps `k ≥ 1`, one per pair: what F should predict.
    pub gaps: Vec<u32>,
}

impl PairSet {
    /// An empty set of pairs of these widths.
    pub fn new(obs_dim: usize, act_dim: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            ..Self::default()
        }
    }

    /// Number of pairs.
    pub fn len(&self) -> usize {
        self.gaps.len()
    }

    /// Whether the set holds no pair.
    pub fn is_empty(&self) -> bool {
        self.gaps.is_empty()
    }

    /// Adds up to `max_pairs` pairs of one trajectory of `n` transitions (`obs`, `next_obs`:
    /// `n × obs_dim`, `actions`: `n × act_dim`, in step order, all before or at the first
    /// success): every pair `(s_t, s_{t+k})`, `1 ≤ k`, `t + k ≤ n`, where `s_{t+k}` is
    /// `next_obs[t + k − 1]`; when there are more than `max_pairs`, a uniform sample of them
    /// without replacement drawn from `rng`.
    pub fn add_trajectory(
        &mut self,
        task: usize,
        obs: &[f32],
        actions: &[f32],
        next_obs: &[f32],
        max_pairs: usize,
        rng: &mut impl Rng,
    ) {
        let n = actions.len() / self.act_dim;
        let steps: Vec<u32> = (0..n as u32).collect();
        self.add_segment(task, &steps, obs, actions, next_obs, max_pairs, rng);
    }

    /// [`PairSet::add_trajectory`] for transitions at step indices `steps` (strictly increasing,
    /// holes allowed, as in selected data): the pair of transitions `t ≤ j` has goal
    /// `next_obs[j]` and gap `steps[j] + 1 − steps[t]` (the TEP buffer's hindsight gap).
    #[allow(clippy::too_many_arguments)] // one trajectory's arrays, as TepBuffer::push_segment
    pub fn add_segment(
        &mut self,
        task: usize,
        steps: &[u32],
        obs: &[f32],
        actions: &[f32],
        next_obs: &[f32],
        max_pairs: usize,
        rng: &mut impl Rng,
    ) {
        let (o, a) = (self.obs_dim, self.act_dim);
        let n = steps.len();
        assert!(
            obs.len() == n * o && next_obs.len() == n * o && actions.len() == n * a,
            "trajectory shapes"
        );
        let total = n * (n + 1) / 2;
        let mut push = |t: usize, j: usize| {
            self.tasks.push(task);
            self.obs.extend_from_slice(&obs[t * o..(t + 1) * o]);
            self.goals.extend_from_slice(&next_obs[j * o..(j + 1) * o]);
            self.actions.extend_from_slice(&actions[t * a..(t + 1) * a]);
            self.gaps.push(steps[j] + 1 - steps[t]);
        };
        // Pair number p ↦ (t, j): pairs listed by t, then j = t..n.
        let pair = |mut p: usize| {
            for t in 0..n {
                let m = n - t;
                if p < m {
                    return (t, t + p);
                }
                p -= m;
            }
            unreachable!("pair index below the total")
        };
        if total <= max_pairs {
            for t in 0..n {
                for j in t..n {
                    push(t, j);
                }
            }
        } else {
            for p in rand::seq::index::sample(rng, total, max_pairs) {
                let (t, j) = pair(p);
                push(t, j);
            }
        }
    }
}

/// Spearman ρ of F per task on `pairs` (`NaN` for a task without pairs), `num_tasks` entries.
pub fn spearman_per_task(pred: &[f64], pairs: &PairSet, num_tasks: usize) -> Vec<f64> {
    (0..num_tasks)
        .map(|k| {
            let (p, g): (Vec<f64>, Vec<f64>) = pred
                .iter()
                .zip(&pairs.gaps)
                .zip(&pairs.tasks)
                .filter(|(_, &t)| t == k)
                .map(|((&p, &g), _)| (p, f64::from(g)))
                .unzip();
            spearman(&p, &g)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn ranks_and_spearman_against_known_values() {
        assert_eq!(ranks(&[10.0, 30.0, 20.0, 20.0]), vec![1.0, 4.0, 2.5, 2.5]);
        // Monotone transform: ρ = 1; reversed: −1.
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let y: Vec<f64> = x.iter().map(|v: &f64| v.powi(3)).collect();
        assert!((spearman(&x, &y) - 1.0).abs() < 1e-12);
        let r: Vec<f64> = x.iter().rev().copied().collect();
        assert!((spearman(&x, &r) + 1.0).abs() < 1e-12);
        // scipy.stats.spearmanr([1,2,3,4,5], [2,1,4,3,5]) = 0.8.
        assert!((spearman(&x, &[2.0, 1.0, 4.0, 3.0, 5.0]) - 0.8).abs() < 1e-12);
        assert!(spearman(&[1.0], &[2.0]).is_nan());
        assert!(spearman(&[1.0, 1.0], &[2.0, 3.0]).is_nan());
    }

    #[test]
    fn median_and_bins() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[]).is_nan());
        let s = score(&[2.0, 5.0, 22.0, 60.0, 90.0], &[1, 5, 20, 50, 100]);
        assert_eq!(s.bins[0].pairs, 2);
        assert!((s.bins[0].median_relative_error - 0.5).abs() < 1e-12);
        assert!((s.bins[1].median_relative_error - 0.1).abs() < 1e-12);
        assert_eq!(s.bins[2].pairs, 2);
        assert!((s.bins[2].median_relative_error - 0.15).abs() < 1e-12);
        assert_eq!(s.bins[3].pairs, 0);
        assert!((s.spearman - 1.0).abs() < 1e-12);
    }

    #[test]
    fn trajectory_pairs_cover_every_gap_once_or_sample_without_replacement() {
        let n = 6;
        let obs: Vec<f32> = (0..n).map(|t| t as f32).collect();
        let next: Vec<f32> = (0..n).map(|t| t as f32 + 1.0).collect();
        let act: Vec<f32> = (0..n).map(|t| t as f32 * 0.1).collect();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut all = PairSet::new(1, 1);
        all.add_trajectory(3, &obs, &act, &next, 1000, &mut rng);
        assert_eq!(all.len(), n * (n + 1) / 2);
        for i in 0..all.len() {
            // The goal is the state k steps after s_t.
            assert_eq!(all.goals[i] - all.obs[i], all.gaps[i] as f32);
            assert_eq!(all.actions[i], all.obs[i] * 0.1);
        }
        let mut some = PairSet::new(1, 1);
        some.add_trajectory(3, &obs, &act, &next, 7, &mut rng);
        assert_eq!(some.len(), 7);
        let mut seen: Vec<(u32, u32)> =
            (0..7).map(|i| (some.obs[i] as u32, some.gaps[i])).collect();
        seen.sort();
        seen.dedup();
        assert_eq!(seen.len(), 7, "no pair twice");
        assert!(some.tasks.iter().all(|&t| t == 3));
    }

    #[test]
    fn segments_with_holes_use_the_step_gap_and_per_task_rho_splits_by_task() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let mut p = PairSet::new(1, 1);
        // Steps 0, 1, 5: the pair (0, 5) is 6 steps apart (goal = state after step 5).
        p.add_segment(
            1,
            &[0, 1, 5],
            &[0.0, 1.0, 5.0],
            &[0.0; 3],
            &[1.0, 2.0, 6.0],
            100,
            &mut rng,
        );
        assert_eq!(p.len(), 6);
        for i in 0..p.len() {
            assert_eq!(p.goals[i] - p.obs[i], p.gaps[i] as f32, "pair {i}");
        }
        let pred: Vec<f64> = p.gaps.iter().map(|&g| f64::from(g)).collect();
        let rho = spearman_per_task(&pred, &p, 3);
        assert!(rho[0].is_nan() && rho[2].is_nan());
        assert!((rho[1] - 1.0).abs() < 1e-12);
    }
}
