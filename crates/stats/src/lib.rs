//! The evaluation statistics of the field, as defined by Agarwal, Schwarzer, Castro, Courville
//! and Bellemare, "Deep Reinforcement Learning at the Edge of the Statistical Precipice"
//! (NeurIPS 2021), and implemented by their `rliable` library (version 1.2.0 is the reference
//! this crate is tested against, see `tests/rliable.rs`).
//!
//! Scores come as a [`ScoreMatrix`] of shape `runs × tasks` (rliable's `(num_runs, num_tasks)`):
//! entry `(n, m)` is the score of run `n` (a seed) on task `m`, in any unit (this project passes
//! success in %). On it:
//! - [`aggregate_mean`]: rliable `metrics.aggregate_mean`, the mean over tasks of the per-task
//!   mean over runs;
//! - [`aggregate_iqm`]: rliable `metrics.aggregate_iqm`, the interquartile mean: the 25 %
//!   trimmed mean of all `runs × tasks` scores pooled (`scipy.stats.trim_mean(scores, 0.25,
//!   axis=None)`: ⌊n/4⌋ scores cut from each end of the sorted n);
//! - [`probability_of_improvement`]: rliable `metrics.probability_of_improvement`, P(X > Y)
//!   per task by the Mann–Whitney U statistic (ties count ½), averaged over tasks;
//! - [`Bootstrap`]: rliable `library.get_interval_estimates` with its defaults `method =
//!   "percentile"`, `task_bootstrap = False`: a **stratified** bootstrap (strata = tasks; each
//!   resample draws, for every task independently, `runs` runs with replacement), and for two
//!   algorithms rliable's `StratifiedIndependentBootstrap` (each resampled on its own). The
//!   interval is the percentile interval of the resampled statistic, with numpy's default
//!   (linear) percentile interpolation, as `arch`'s `conf_int(method="percentile")`.
//!
//! Unlike rliable (numpy's global RNG), the resampling here is deterministic: a ChaCha8 stream
//! from a fixed seed ([`DEFAULT_SEED`]), restarted for every interval, so the same scores give
//! the same interval on every machine and in any order of calls.

#![warn(missing_docs)]

use rand_chacha::rand_core::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Resamples of a bootstrap interval unless told otherwise. rliable's default is 50 000; 10 000
/// puts the Monte-Carlo error of a 95 % percentile endpoint well under the displayed precision
/// of the committed tables for their score matrices, and keeps `terl report` fast.
pub const DEFAULT_REPS: usize = 10_000;

/// Seed of the ChaCha8 stream every bootstrap interval starts from.
pub const DEFAULT_SEED: u64 = 0x7e71_5eed;

/// Coverage of the intervals unless told otherwise (rliable's `confidence_interval_size`).
pub const DEFAULT_CONFIDENCE: f64 = 0.95;

/// What the statistics refuse.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StatsError {
    /// A matrix needs at least one run and one task.
    #[error("a score matrix needs at least one run and one task (got {runs} × {tasks})")]
    Empty {
        /// Runs (rows) given.
        runs: usize,
        /// Tasks (columns) given.
        tasks: usize,
    },
    /// The data length is not `runs × tasks`, or the rows differ in length.
    #[error("scores do not form a runs × tasks matrix: {0}")]
    Shape(String),
    /// NaN or ±∞ among the scores.
    #[error("score ({run}, {task}) is not finite: {value}")]
    NotFinite {
        /// Row (run) of the score, 0-based.
        run: usize,
        /// Column (task) of the score, 0-based.
        task: usize,
        /// The offending value.
        value: f64,
    },
    /// Two algorithms compared on different numbers of tasks.
    #[error("the two score matrices have {0} and {1} tasks")]
    TaskMismatch(usize, usize),
    /// Coverage outside (0, 1) or no resamples.
    #[error("bootstrap needs reps ≥ 1 and a confidence in (0, 1) (got {reps}, {confidence})")]
    Bootstrap {
        /// Resamples asked for.
        reps: usize,
        /// Coverage asked for.
        confidence: f64,
    },
}

/// Scores of shape `runs × tasks`, row-major: `data[run * tasks + task]`. All finite.
#[derive(Debug, Clone, PartialEq)]
pub struct ScoreMatrix {
    runs: usize,
    tasks: usize,
    data: Vec<f64>,
}

impl ScoreMatrix {
    /// A matrix from row-major data of length `runs × tasks`.
    pub fn new(runs: usize, tasks: usize, data: Vec<f64>) -> Result<Self, StatsError> {
        if runs == 0 || tasks == 0 {
            return Err(StatsError::Empty { runs, tasks });
        }
        if data.len() != runs * tasks {
            return Err(StatsError::Shape(format!(
                "{} values for {runs} × {tasks}",
                data.len()
            )));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(StatsError::NotFinite {
                run: i / tasks,
                task: i % tasks,
                value: data[i],
            });
        }
        Ok(Self { runs, tasks, data })
    }

    /// A matrix from one row per run, each with one score per task.
    pub fn from_rows(rows: &[Vec<f64>]) -> Result<Self, StatsError> {
        let tasks = rows.first().map_or(0, Vec::len);
        if let Some((i, r)) = rows.iter().enumerate().find(|(_, r)| r.len() != tasks) {
            return Err(StatsError::Shape(format!(
                "row {i} has {} scores, row 0 has {tasks}",
                r.len()
            )));
        }
        Self::new(rows.len(), tasks, rows.concat())
    }

    /// Number of runs (rows).
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// Number of tasks (columns).
    pub fn tasks(&self) -> usize {
        self.tasks
    }

    /// Score of `run` on `task`.
    pub fn get(&self, run: usize, task: usize) -> f64 {
        self.data[run * self.tasks + task]
    }

    /// The scores of one task over runs.
    pub fn column(&self, task: usize) -> impl Iterator<Item = f64> + '_ {
        (0..self.runs).map(move |r| self.get(r, task))
    }

    /// A stratified resample into `out` (same shape): every entry `(n, m)` is `(j, m)` for a
    /// run `j` drawn uniformly with replacement, independently per entry (rliable
    /// `StratifiedBootstrap.update_indices`: `np.random.choice(num_runs, (num_runs,
    /// num_tasks))`).
    fn resample_into(&self, rng: &mut ChaCha8Rng, out: &mut ScoreMatrix) {
        for r in 0..self.runs {
            for t in 0..self.tasks {
                let j = uniform_index(rng, self.runs);
                out.data[r * self.tasks + t] = self.data[j * self.tasks + t];
            }
        }
    }
}

/// A uniform integer in `0..n` (`n ≥ 1`) from the stream, without modulo bias (Lemire's
/// multiply-and-reject), written out so the draws never depend on a `rand` version.
fn uniform_index(rng: &mut ChaCha8Rng, n: usize) -> usize {
    let n = n as u64;
    let threshold = n.wrapping_neg() % n;
    loop {
        let m = u128::from(rng.next_u64()) * u128::from(n);
        if (m as u64) >= threshold {
            return (m >> 64) as usize;
        }
    }
}

/// rliable `metrics.aggregate_mean`: the mean over tasks of each task's mean over runs (for a
/// full matrix, the mean of all its scores). Unit: that of the scores.
pub fn aggregate_mean(scores: &ScoreMatrix) -> f64 {
    let task_means = (0..scores.tasks).map(|t| scores.column(t).sum::<f64>() / scores.runs as f64);
    task_means.sum::<f64>() / scores.tasks as f64
}

/// rliable `metrics.aggregate_iqm`: the interquartile mean of all `runs × tasks` scores pooled,
/// i.e. `scipy.stats.trim_mean(scores, proportiontocut=0.25, axis=None)`: of the `n` sorted
/// scores, `⌊n/4⌋` are cut from each end and the rest averaged (for `n < 4` nothing is cut and
/// it is the mean). Unit: that of the scores.
pub fn aggregate_iqm(scores: &ScoreMatrix) -> f64 {
    let mut values = scores.data.clone();
    values.sort_by(f64::total_cmp);
    let cut = values.len() / 4;
    let kept = &values[cut..values.len() - cut];
    kept.iter().sum::<f64>() / kept.len() as f64
}

/// rliable `metrics.probability_of_improvement(scores_x, scores_y)`: per task, the probability
/// that a run of X scores higher than a run of Y, `P(X_m > Y_m) + ½ P(X_m = Y_m)` over all
/// `runs_x × runs_y` pairs (the Mann–Whitney U statistic of X over Y divided by `runs_x ·
/// runs_y`, as `scipy.stats.mannwhitneyu(..., alternative="greater").statistic`), averaged over
/// tasks. In [0, 1]; 0.5 means no difference. The two matrices may differ in runs, not in tasks
/// (task `m` of one is task `m` of the other).
pub fn probability_of_improvement(x: &ScoreMatrix, y: &ScoreMatrix) -> Result<f64, StatsError> {
    if x.tasks != y.tasks {
        return Err(StatsError::TaskMismatch(x.tasks, y.tasks));
    }
    Ok(poi_unchecked(x, y))
}

fn poi_unchecked(x: &ScoreMatrix, y: &ScoreMatrix) -> f64 {
    let pairs = (x.runs * y.runs) as f64;
    let per_task = (0..x.tasks).map(|t| {
        let mut u = 0.0;
        for a in x.column(t) {
            for b in y.column(t) {
                if a > b {
                    u += 1.0;
                } else if a == b {
                    u += 0.5;
                }
            }
        }
        u / pairs
    });
    per_task.sum::<f64>() / x.tasks as f64
}

/// A point estimate with its bootstrap confidence interval, in the unit of the statistic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// The statistic on the scores themselves.
    pub point: f64,
    /// Lower end: the `(1 − confidence) / 2` percentile of the resampled statistic.
    pub lower: f64,
    /// Upper end: the `(1 + confidence) / 2` percentile of the resampled statistic.
    pub upper: f64,
}

/// Settings of a stratified percentile bootstrap (rliable `get_interval_estimates` with
/// `method = "percentile"`, `task_bootstrap = False`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bootstrap {
    /// Resamples (rliable's `reps`).
    pub reps: usize,
    /// Coverage in (0, 1) (rliable's `confidence_interval_size`).
    pub confidence: f64,
    /// Seed of the ChaCha8 stream; every interval restarts it.
    pub seed: u64,
}

impl Default for Bootstrap {
    fn default() -> Self {
        Self {
            reps: DEFAULT_REPS,
            confidence: DEFAULT_CONFIDENCE,
            seed: DEFAULT_SEED,
        }
    }
}

impl Bootstrap {
    /// [`DEFAULT_CONFIDENCE`] and [`DEFAULT_SEED`] with `reps` resamples.
    pub fn with_reps(reps: usize) -> Self {
        Self {
            reps,
            ..Self::default()
        }
    }

    fn check(&self) -> Result<(), StatsError> {
        if self.reps == 0 || !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(StatsError::Bootstrap {
                reps: self.reps,
                confidence: self.confidence,
            });
        }
        Ok(())
    }

    fn interval_of(&self, point: f64, mut values: Vec<f64>) -> Interval {
        values.sort_by(f64::total_cmp);
        let tail = 100.0 * (1.0 - self.confidence) / 2.0;
        Interval {
            point,
            lower: percentile_sorted(&values, tail),
            upper: percentile_sorted(&values, 100.0 - tail),
        }
    }

    /// `statistic` on `scores` and its stratified percentile-bootstrap interval: `reps`
    /// resamples, each drawing per task `runs` runs with replacement.
    pub fn interval(
        &self,
        scores: &ScoreMatrix,
        statistic: impl Fn(&ScoreMatrix) -> f64,
    ) -> Result<Interval, StatsError> {
        self.check()?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let mut sample = scores.clone();
        let values = (0..self.reps)
            .map(|_| {
                scores.resample_into(&mut rng, &mut sample);
                statistic(&sample)
            })
            .collect();
        Ok(self.interval_of(statistic(scores), values))
    }

    /// [`aggregate_iqm`] with its interval.
    pub fn iqm(&self, scores: &ScoreMatrix) -> Result<Interval, StatsError> {
        self.interval(scores, aggregate_iqm)
    }

    /// [`aggregate_mean`] with its interval.
    pub fn mean(&self, scores: &ScoreMatrix) -> Result<Interval, StatsError> {
        self.interval(scores, aggregate_mean)
    }

    /// [`probability_of_improvement`] of X over Y with its interval: each resample draws X and
    /// Y independently, each stratified by task (rliable `StratifiedIndependentBootstrap`).
    pub fn probability_of_improvement(
        &self,
        x: &ScoreMatrix,
        y: &ScoreMatrix,
    ) -> Result<Interval, StatsError> {
        self.check()?;
        let point = probability_of_improvement(x, y)?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let (mut sx, mut sy) = (x.clone(), y.clone());
        let values = (0..self.reps)
            .map(|_| {
                x.resample_into(&mut rng, &mut sx);
                y.resample_into(&mut rng, &mut sy);
                poi_unchecked(&sx, &sy)
            })
            .collect();
        Ok(self.interval_of(point, values))
    }
}

/// numpy's `np.percentile(values, q)` with its default `method="linear"`: position
/// `(n − 1) · q / 100` in the sorted values, linearly interpolated. `q` in [0, 100]; `sorted`
/// non-empty and ascending.
pub fn percentile_sorted(sorted: &[f64], q: f64) -> f64 {
    let pos = (q / 100.0) * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    let frac = pos - lo as f64;
    // numpy's `_lerp`: a + (b − a)·t, taken from the upper end when t ≥ ½.
    let (a, b) = (sorted[lo], sorted[hi]);
    if frac >= 0.5 {
        b - (b - a) * (1.0 - frac)
    } else {
        a + (b - a) * frac
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(rows: &[&[f64]]) -> ScoreMatrix {
        ScoreMatrix::from_rows(&rows.iter().map(|r| r.to_vec()).collect::<Vec<_>>()).unwrap()
    }

    #[test]
    fn iqm_mean_and_poi_by_hand() {
        // 2 runs × 4 tasks: sorted 0 1 2 3 4 5 6 7, cut 2 each end → (2+3+4+5)/4 = 3.5.
        let s = m(&[&[0.0, 7.0, 2.0, 5.0], &[6.0, 1.0, 4.0, 3.0]]);
        assert_eq!(aggregate_iqm(&s), 3.5);
        assert_eq!(aggregate_mean(&s), 3.5);
        // 3 scores: nothing cut.
        assert_eq!(aggregate_iqm(&m(&[&[0.0, 0.0, 9.0]])), 3.0);
        // 5 scores: one cut each end.
        assert_eq!(aggregate_iqm(&m(&[&[10.0, 0.0, 1.0, 2.0, 3.0]])), 2.0);
        // P(X > Y): task 0: x {1, 3} vs y {2, 2}: (0 + 0 + 1 + 1) / 4 = 0.5; task 1: x {5, 5}
        // vs y {5, 0}: (0.5 + 1 + 0.5 + 1) / 4 = 0.75 → 0.625.
        let x = m(&[&[1.0, 5.0], &[3.0, 5.0]]);
        let y = m(&[&[2.0, 5.0], &[2.0, 0.0]]);
        assert_eq!(probability_of_improvement(&x, &y).unwrap(), 0.625);
        assert_eq!(probability_of_improvement(&y, &x).unwrap(), 0.375);
        assert!(probability_of_improvement(&x, &m(&[&[1.0]])).is_err());
    }

    #[test]
    fn percentile_matches_numpy_linear() {
        let v = [1.0, 2.0, 4.0, 8.0];
        // np.percentile([1, 2, 4, 8], [0, 2.5, 50, 97.5, 100]) = 1, 1.075, 3, 7.7, 8.
        let want = [1.0, 1.075, 3.0, 7.7, 8.0];
        for (q, w) in [0.0, 2.5, 50.0, 97.5, 100.0].into_iter().zip(want) {
            assert!((percentile_sorted(&v, q) - w).abs() < 1e-12, "{q}");
        }
    }

    #[test]
    fn bootstrap_is_deterministic_and_brackets_the_point() {
        let s = m(&[&[10.1, 80.2, 0.3], &[30.4, 90.5, 0.6], &[20.7, 60.8, 10.9]]);
        let b = Bootstrap::with_reps(2000);
        let a = b.iqm(&s).unwrap();
        assert_eq!(a, b.iqm(&s).unwrap(), "same seed, same interval");
        assert!(a.lower <= a.point && a.point <= a.upper, "{a:?}");
        assert!(a.lower < a.upper);
        let other = Bootstrap { seed: 1, ..b }.iqm(&s).unwrap();
        assert_ne!(a, other, "another seed resamples differently");
        // One run: every resample is the matrix itself.
        let one = m(&[&[1.0, 2.0]]);
        let i = b.mean(&one).unwrap();
        assert_eq!((i.point, i.lower, i.upper), (1.5, 1.5, 1.5));
        // A constant task column stays constant under stratified resampling: the mean of
        // [[0, 5], [10, 5]] resamples only the first column.
        let i = b.mean(&m(&[&[0.0, 5.0], &[10.0, 5.0]])).unwrap();
        assert_eq!((i.lower, i.upper), (2.5, 7.5));
        assert!(Bootstrap { reps: 0, ..b }.mean(&one).is_err());
        assert!(Bootstrap {
            confidence: 1.0,
            ..b
        }
        .mean(&one)
        .is_err());
    }

    #[test]
    fn matrices_are_checked() {
        assert!(ScoreMatrix::new(0, 3, vec![]).is_err());
        assert!(ScoreMatrix::new(2, 2, vec![1.0; 3]).is_err());
        assert!(ScoreMatrix::new(1, 2, vec![1.0, f64::NAN]).is_err());
        assert!(ScoreMatrix::from_rows(&[vec![1.0, 2.0], vec![1.0]]).is_err());
        let s = ScoreMatrix::new(2, 3, (0..6).map(f64::from).collect()).unwrap();
        assert_eq!((s.runs(), s.tasks(), s.get(1, 2)), (2, 3, 5.0));
    }
}
