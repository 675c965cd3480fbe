//! The tanh-squashed diagonal Gaussian policy head used by SAC.
//!
//! A network outputs `[mean (A) | log_std (A)]` per row. Sampling is reparameterised:
//! `u = mean + exp(clamp(log_std)) · ε`, `a = tanh(u)` with `ε ~ N(0, I)` drawn by the caller, so
//! gradients flow through `mean` and `log_std`. The log-density of `a` is the Gaussian log-density
//! of `u` minus `Σ ln(1 − tanh²u)`, written in the overflow-free form
//! `ln(1 − tanh²u) = 2·(ln 2 − u − softplus(−2u))`.
//!
//! `log_std` is clamped to `[LOG_STD_MIN, LOG_STD_MAX] = [−20, 2]` (the bounds of Meta-World's
//! reference MTSAC policy); the clamp passes no gradient outside the range, as `torch.clamp`.

use crate::scalar::Float;
use rand::Rng;

/// Lower clamp of the log standard deviation.
pub const LOG_STD_MIN: f64 = -20.0;
/// Upper clamp of the log standard deviation.
pub const LOG_STD_MAX: f64 = 2.0;

/// Fills `out` with independent standard-normal samples (Box–Muller in `f64`, so the stream
/// is the same for `f32` and `f64` networks).
pub fn fill_standard_normal<T: Float>(rng: &mut impl Rng, out: &mut [T]) {
    let mut chunks = out.chunks_exact_mut(2);
    for pair in &mut chunks {
        let (a, b) = box_muller(rng);
        pair[0] = T::of(a);
        pair[1] = T::of(b);
    }
    if let [last] = chunks.into_remainder() {
        *last = T::of(box_muller(rng).0);
    }
}

fn box_muller(rng: &mut impl Rng) -> (f64, f64) {
    // 1 − U lies in (0, 1], so the logarithm is finite.
    let u1: f64 = 1.0 - rng.gen::<f64>();
    let u2: f64 = rng.gen::<f64>();
    let r = (-2.0 * u1.ln()).sqrt();
    let theta = std::f64::consts::TAU * u2;
    (r * theta.cos(), r * theta.sin())
}

#[inline(always)]
fn clamp_log_std<T: Float>(x: T) -> (T, bool) {
    let (lo, hi) = (T::of(LOG_STD_MIN), T::of(LOG_STD_MAX));
    if x < lo {
        (lo, false)
    } else if x > hi {
        (hi, false)
    } else {
        (x, true)
    }
}

/// Reparameterised sample: writes `actions` (rows × A) and `log_prob` (rows) from the head
/// output `head` (rows × 2A) and noise `eps` (rows × A).
pub fn sample<T: Float>(
    head: &[T],
    eps: &[T],
    act_dim: usize,
    actions: &mut [T],
    log_prob: &mut [T],
) {
    let rows = log_prob.len();
    assert_eq!(head.len(), rows * 2 * act_dim);
    assert_eq!(eps.len(), rows * act_dim);
    assert_eq!(actions.len(), rows * act_dim);
    let half_ln_2pi = T::of(0.5 * (2.0 * std::f64::consts::PI).ln());
    let (ln2, two, half) = (T::of(std::f64::consts::LN_2), T::of(2.0), T::of(0.5));
    for r in 0..rows {
        let h = &head[r * 2 * act_dim..(r + 1) * 2 * act_dim];
        let (mean, log_std) = h.split_at(act_dim);
        let e = &eps[r * act_dim..(r + 1) * act_dim];
        let a = &mut actions[r * act_dim..(r + 1) * act_dim];
        let mut lp = T::of(0.0);
        for j in 0..act_dim {
            let (ls, _) = clamp_log_std(log_std[j]);
            let u = mean[j] + ls.exp() * e[j];
            a[j] = u.tanh();
            let log_one_minus_tanh2 = two * (ln2 - u - (-two * u).softplus());
            lp += -half * e[j] * e[j] - ls - half_ln_2pi - log_one_minus_tanh2;
        }
        log_prob[r] = lp;
    }
}

/// The deterministic (evaluation) action `tanh(mean)`.
pub fn mean_action<T: Float>(head: &[T], act_dim: usize, actions: &mut [T]) {
    for (h, a) in head
        .chunks_exact(2 * act_dim)
        .zip(actions.chunks_exact_mut(act_dim))
    {
        for (aj, &m) in a.iter_mut().zip(&h[..act_dim]) {
            *aj = m.tanh();
        }
    }
}

/// Backward of [`sample`]: given `dL/d actions` (rows × A) and `dL/d log_prob` (rows), writes
/// `dL/d head` (rows × 2A). `actions` must be the output of [`sample`] for the same inputs.
pub fn sample_backward<T: Float>(
    head: &[T],
    eps: &[T],
    actions: &[T],
    d_actions: &[T],
    d_log_prob: &[T],
    act_dim: usize,
    d_head: &mut [T],
) {
    let rows = d_log_prob.len();
    assert_eq!(head.len(), rows * 2 * act_dim);
    assert_eq!(d_head.len(), rows * 2 * act_dim);
    assert_eq!(d_actions.len(), rows * act_dim);
    let (zero, one, two) = (T::of(0.0), T::of(1.0), T::of(2.0));
    for r in 0..rows {
        let h = &head[r * 2 * act_dim..(r + 1) * 2 * act_dim];
        let log_std = &h[act_dim..];
        let (d_mean, d_log_std) =
            d_head[r * 2 * act_dim..(r + 1) * 2 * act_dim].split_at_mut(act_dim);
        let dlp = d_log_prob[r];
        for j in 0..act_dim {
            let k = r * act_dim + j;
            let a = actions[k];
            // d logp / du = 2·tanh(u) (from −ln(1 − tanh²u)); da/du = 1 − tanh²u.
            let g_u = d_actions[k] * (one - a * a) + dlp * two * a;
            d_mean[j] = g_u;
            let (ls, inside) = clamp_log_std(log_std[j]);
            // u depends on log_std through exp(log_std)·ε; the Gaussian term contributes −1.
            d_log_std[j] = if inside {
                g_u * ls.exp() * eps[k] - dlp
            } else {
                zero
            };
        }
    }
}
