//! PTR selection: GAE against the explicit sum, priority ordering, ranking across a pool of
//! trajectories, the squashed-policy entropy, the 85 % gate.

use terl_rl::ptr::{
    gae, gaussian_entropy, squashed_gaussian_entropy, top_k, trajectory_priorities, PtrConfig,
    PtrPool, SuccessGate, TrajectoryEnd,
};

/// `A_j = Σ_{l=0}^{T−j−1} (γλ)^l δ_{j+l}` written out as the explicit sum of Eq. 6, with
/// `δ_t = r_t + γ·V(s_{t+1}) − V(s_t)` from Eq. 7 and `V(s_T)` given.
fn explicit_gae(r: &[f64], v: &[f64], v_end: f64, gamma: f64, lambda: f64) -> Vec<f64> {
    let n = r.len();
    let value = |t: usize| if t == n { v_end } else { v[t] };
    let delta: Vec<f64> = (0..n)
        .map(|t| r[t] + gamma * value(t + 1) - value(t))
        .collect();
    (0..n)
        .map(|j| {
            (0..n - j)
                .map(|l| (gamma * lambda).powi(l as i32) * delta[j + l])
                .sum()
        })
        .collect()
}

#[test]
fn gae_matches_the_explicit_sum_and_a_hand_example() {
    let (g, l) = (0.99, 0.95);
    // Hand example, T = 2, terminated: δ_1 = 2 − 0.5 = 1.5, δ_0 = 1 + 0.99·0.5 − 1 = 0.495,
    // A_1 = 1.5, A_0 = 0.495 + 0.9405·1.5 = 1.90575.
    let a = gae(&[1.0, 2.0], &[1.0, 0.5], TrajectoryEnd::Terminated, g, l);
    assert!((a[1] - 1.5).abs() < 1e-12, "{a:?}");
    assert!((a[0] - 1.90575).abs() < 1e-12, "{a:?}");

    let r = [0.3, -1.0, 2.5, 0.0, 1.25, 4.0, -0.5];
    let v = [1.0, 0.7, -0.2, 3.0, 2.2, 0.1, 1.5];
    for (end, v_end) in [
        (TrajectoryEnd::Terminated, 0.0),
        (TrajectoryEnd::Truncated { last_value: 2.75 }, 2.75),
    ] {
        let fast = gae(&r, &v, end, g, l);
        let slow = explicit_gae(&r, &v, v_end, g, l);
        for (x, y) in fast.iter().zip(&slow) {
            assert!((x - y).abs() < 1e-12, "{end:?}: {fast:?} vs {slow:?}");
        }
    }
    // Truncation bootstraps: only the last δ changes, by γ·V(s_T), discounted back by (γλ)^l.
    let term = gae(&r, &v, TrajectoryEnd::Terminated, g, l);
    let trunc = gae(&r, &v, TrajectoryEnd::Truncated { last_value: 1.0 }, g, l);
    let n = r.len();
    for j in 0..n {
        let expect = g * (g * l).powi((n - 1 - j) as i32);
        assert!((trunc[j] - term[j] - expect).abs() < 1e-12);
    }
}

#[test]
fn priority_is_weighted_mean_gae_plus_entropy_and_ranks_highest_first() {
    let cfg = PtrConfig::default();
    assert_eq!(cfg.priority(2.0, 1.0), 0.6 * 2.0 + 0.4 * 1.0);
    let r = [1.0, 0.0, 1.0];
    let v = [0.5, 0.5, 0.5];
    let h = [0.1, -0.3, 0.9];
    let (p, mean) = trajectory_priorities(&cfg, &r, &v, TrajectoryEnd::Terminated, &h);
    let adv = gae(&r, &v, TrajectoryEnd::Terminated, 0.99, 0.95);
    assert!((mean - adv.iter().sum::<f64>() / 3.0).abs() < 1e-12);
    for t in 0..3 {
        assert!((p[t] - (0.6 * mean + 0.4 * h[t])).abs() < 1e-12);
    }
    // Within a trajectory the order is the entropy order.
    assert_eq!(top_k(&p, 3), vec![2, 0, 1]);
    // Higher mean GAE ranks a whole trajectory higher at equal entropy.
    let (good, _) = trajectory_priorities(&cfg, &[5.0; 3], &v, TrajectoryEnd::Terminated, &h);
    assert!(good.iter().zip(&p).all(|(g, b)| g > b));
    // NaN ranks last, ties keep the earlier index.
    assert_eq!(top_k(&[1.0, f64::NAN, 3.0, 1.0], 4), vec![2, 0, 3, 1]);
    // Entropy of a unit Gaussian per dimension: ½·ln(2πe) ≈ 1.4189.
    assert!((gaussian_entropy(&[0.0, 0.0]) - 2.0 * 1.418_938_533_204_672_7).abs() < 1e-12);
}

/// Eq. 9 ranks trajectories against each other: with the same states (values, entropies) the
/// trajectory with the higher advantage is selected first, whole, whatever the arrival order —
/// even though each trajectory alone would fill a 512-transition batch.
#[test]
fn the_pool_selects_the_higher_advantage_trajectory_first() {
    let cfg = PtrConfig {
        pool_trajectories: 3,
        ..Default::default()
    };
    let n = 600;
    let v = vec![0.5; n];
    let h: Vec<f64> = (0..n).map(|t| ((t * 7) % 13) as f64 * 0.05).collect();
    let end = TrajectoryEnd::Truncated { last_value: 0.5 };
    // Arrival order: low, high, middle advantage (rewards 0, 10, 2 per step).
    let mut pool = PtrPool::new(&cfg);
    let mut out = Vec::new();
    for (id, reward) in [(0usize, 0.0), (1, 10.0), (2, 2.0)] {
        let (p, _) = trajectory_priorities(&cfg, &vec![reward; n], &v, end, &h);
        out = pool.push_trajectory(p.into_iter().enumerate().map(|(t, p)| (p, (id, t))));
        if id < 2 {
            assert!(out.is_empty(), "the pool ranks only when full");
        }
    }
    assert_eq!(pool.pending(), (0, 0), "the pool empties after ranking");
    let selected = cfg.selected_of(3 * n);
    assert_eq!(selected, 450); // ceil(0.25 · 1800)
    assert_eq!(out.iter().map(Vec::len).collect::<Vec<_>>(), vec![450]);
    let flat: Vec<(f64, (usize, usize))> = out.into_iter().flatten().collect();
    assert!(flat.windows(2).all(|w| w[0].0 >= w[1].0), "highest P first");
    assert!(
        flat.iter().all(|(_, (id, _))| *id == 1),
        "the top quarter is all from the high-advantage trajectory"
    );
    assert_eq!(pool.counts(), (1, 3 * n as u64, 450));
}

/// Selections leave a ranked pool in batches of `batch_size`, best first, and a partial pool
/// can be flushed.
#[test]
fn ranked_pools_leave_in_batches_of_batch_size() {
    let cfg = PtrConfig {
        pool_trajectories: 2,
        top_fraction: 0.5,
        ..Default::default()
    };
    let mut pool = PtrPool::new(&cfg);
    let first: Vec<(f64, usize)> = (0..1000).map(|i| (((i * 37) % 1000) as f64, i)).collect();
    assert!(pool.push_trajectory(first).is_empty());
    assert!(
        pool.push_trajectory(Vec::<(f64, usize)>::new()).is_empty(),
        "empty: not counted"
    );
    let second: Vec<(f64, usize)> = (1000..2200).map(|i| (i as f64 * 0.5, i)).collect();
    let out = pool.push_trajectory(second);
    assert_eq!(
        out.iter().map(Vec::len).collect::<Vec<_>>(),
        vec![512, 512, 76]
    );
    let flat: Vec<f64> = out.iter().flatten().map(|x| x.0).collect();
    let mut all: Vec<f64> = (0..1000)
        .map(|i| ((i * 37) % 1000) as f64)
        .chain((1000..2200).map(|i| i as f64 * 0.5))
        .collect();
    all.sort_by(|a, b| b.total_cmp(a));
    assert_eq!(flat, all[..1100].to_vec());
    assert!(pool.push_trajectory([(1.0, 7usize), (2.0, 8)]).is_empty());
    let rest = pool.flush();
    assert_eq!(rest, vec![vec![(2.0, 8)]]);
    assert!(pool.flush().is_empty());
    assert!(PtrConfig {
        pool_trajectories: 0,
        ..Default::default()
    }
    .validate()
    .is_err());
}

/// The entropy PTR uses is that of the executed, tanh-squashed policy: `E[−log π(a|s)]` with the
/// tanh Jacobian, checked against a Monte-Carlo mean of `−log π(a|s)` of sampled actions.
#[test]
fn squashed_entropy_matches_a_monte_carlo_estimate_of_minus_log_pi() {
    use rand::Rng;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let normal = |rng: &mut ChaCha8Rng| {
        let (u1, u2): (f64, f64) = (rng.gen::<f64>().max(1e-300), rng.gen());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    };
    for (mean, log_std) in [
        (vec![0.0, 0.0], vec![0.0, 0.0]),
        (vec![0.3, -1.2], vec![-1.0, 0.5]),
        (vec![2.5, 0.0], vec![-3.0, 2.0]),
        (vec![-0.7], vec![-20.0]),
    ] {
        let got = squashed_gaussian_entropy(&mean, &log_std);
        let draws = 200_000;
        let (mut sum, mut sq) = (0.0, 0.0);
        for _ in 0..draws {
            let mut nlp = 0.0;
            for (&m, &l) in mean.iter().zip(&log_std) {
                let e = normal(&mut rng);
                let u = m + l.exp() * e;
                // −log N(u; m, σ) + ln(1 − tanh²u), the latter in a stable form.
                let log_one_minus_t2 =
                    2.0 * (std::f64::consts::LN_2 - u - (-2.0 * u).exp().ln_1p());
                nlp += 0.5 * e * e + l + 0.5 * (2.0 * std::f64::consts::PI).ln() + log_one_minus_t2;
            }
            sum += nlp;
            sq += nlp * nlp;
        }
        let mc = sum / draws as f64;
        let se = ((sq / draws as f64 - mc * mc) / draws as f64).sqrt();
        assert!(
            (got - mc).abs() < 4.0 * se + 2e-3,
            "mean {mean:?} log_std {log_std:?}: quadrature {got}, Monte Carlo {mc} ± {se}"
        );
        assert!(got <= gaussian_entropy(&log_std) + 1e-12);
    }
    // A saturated mean makes the executed action nearly deterministic: lower entropy.
    assert!(
        squashed_gaussian_entropy(&[3.0], &[-1.0]) < squashed_gaussian_entropy(&[0.0], &[-1.0])
    );
}

#[test]
fn gate_opens_at_85_percent_rolling_success_and_latches() {
    let cfg = PtrConfig {
        success_window: 20,
        ..Default::default()
    };
    let mut gate = SuccessGate::new(&cfg, 2);
    // 16/20 = 80 %: closed.
    for i in 0..20 {
        gate.record(0, i % 5 != 0);
    }
    assert!((gate.success_rate(0) - 0.8).abs() < 1e-12);
    assert!(!gate.is_open(0));
    // Sliding in 1 more success over a failure: 17/20 = 85 % opens it.
    assert!(gate.record(0, true)); // drops i=0 (failure) → 17/20
    assert!((gate.success_rate(0) - 0.85).abs() < 1e-12);
    assert!(gate.is_open(0));
    // Task 1 is separate; too few episodes never opens even at 100 %.
    for _ in 0..19 {
        gate.record(1, true);
    }
    assert!(!gate.is_open(1));
    assert!(gate.record(1, true));
    // Latching: failures afterwards keep it open; without latch it closes.
    for _ in 0..20 {
        gate.record(0, false);
    }
    assert!(gate.is_open(0));
    let mut loose = SuccessGate::new(
        &PtrConfig {
            latch: false,
            ..cfg.clone()
        },
        1,
    );
    for _ in 0..20 {
        loose.record(0, true);
    }
    assert!(loose.is_open(0));
    assert!(!loose.record(0, false) || loose.success_rate(0) >= 0.85);
    for _ in 0..3 {
        loose.record(0, false);
    }
    assert!(!loose.is_open(0));
    // Config round trip and validation.
    let t = PtrConfig::from_toml("top_fraction = 0.5\nsuccess_threshold = 0.9").unwrap();
    assert_eq!(t.top_fraction, 0.5);
    assert!(PtrConfig::from_toml("top_fraction = 0.0").is_err());
    assert!(PtrConfig::from_toml("bogus = 1").is_err());
}
