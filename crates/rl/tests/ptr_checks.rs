//! PTR selection: GAE against the explicit sum, priority ordering, batch ranking, the 85 % gate.

use terl_rl::ptr::{
    gae, gaussian_entropy, top_k, trajectory_priorities, PtrBatcher, PtrConfig, SuccessGate,
    TrajectoryEnd,
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

#[test]
fn batcher_selects_the_top_fraction_of_each_512_batch() {
    let cfg = PtrConfig {
        top_fraction: 0.1,
        ..Default::default()
    };
    assert_eq!(cfg.batch_size, 512);
    assert_eq!(cfg.selected_per_batch(), 52);
    let mut b = PtrBatcher::new(&cfg);
    // 1100 items with priority = a permutation-ish function of the index.
    let items: Vec<(f64, usize)> = (0..1100).map(|i| (((i * 37) % 1100) as f64, i)).collect();
    let sel = b.extend(items.iter().copied());
    assert_eq!(sel.len(), 2 * 52);
    assert_eq!(b.pending(), 1100 - 1024);
    for (k, chunk) in sel.chunks(52).enumerate() {
        let batch = &items[k * 512..(k + 1) * 512];
        let mut prios: Vec<f64> = batch.iter().map(|x| x.0).collect();
        prios.sort_by(|a, b| b.total_cmp(a));
        let got: Vec<f64> = chunk.iter().map(|x| x.0).collect();
        assert_eq!(
            got,
            prios[..52].to_vec(),
            "batch {k} not the top 52, highest first"
        );
        assert!(chunk
            .iter()
            .all(|x| (k * 512..(k + 1) * 512).contains(&x.1)));
    }
    let rest = b.flush();
    assert_eq!(rest.len(), 8); // ceil(52 · 76 / 512)
    assert_eq!(b.counts(), (3, 1100, 112));
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
