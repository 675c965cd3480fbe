//! On a generated grid problem with known step distances, the trained reachability net F
//! predicts held-out distances within 10 % on average, and each distance up to 6 within 12 %.
//!
//! Problem: a point on a lattice takes king moves: action `a ∈ [−1, 1]²` (uniform in the data, so
//! every action AN can output is covered) moves it by `round(a)` lattice units per coordinate.
//! Trajectories are random walks of `LEN` steps from random continuous starts. The fewest steps
//! from `s` to `s'` is the Chebyshev distance `D = max(|dx|, |dy|)`, and with a first move
//! towards the goal `F(s, s', a) = D`. The data's step gaps are longer than `D` (random walks
//! wander): only the bootstrapped `1 + F̃(s_{t+1}, s', ÃN(s_{t+1}, s'))` (a minimum over actions
//! through AN) can bring F down to the shortest distance, so this checks both losses and the
//! targets together. Evaluation uses fresh walks (unseen continuous states). Release only:
//! `cargo test --release -p terl-rl --test tep_distance`.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;
use terl_rl::{Tep, TepBatch, TepBuffer, TepConfig};

const LEN: usize = 20;
const SCALE: f32 = 0.1;
const MAX_D: usize = 8;
/// Distances whose mean prediction is asserted within [`MAX_BIAS`]. F underestimates
/// increasingly with distance (the minimum over actions in the bootstrap picks up the fit's
/// noise at every step, like max-overestimation in Q-learning; the paper has no correction for
/// it). Measured with F's softplus output (F ≥ 0 by construction) at this seed and budget:
/// +7.7 % at D = 1, +3.3 % at 2, −2.2 % at 3, −6.9 % at 4, −9.8 % at 5, −11.3 % at 6, −11.7 % at
/// 7 and 8 (with the earlier linear output: −2.7 %, −6 %, −8.5 %, −9.9 %, −11 %, −11.6 % at
/// D = 3..8). D = 7, 8 are printed, not asserted.
const ASSERT_MAX_D: usize = 6;
/// Largest accepted per-distance bias of the mean prediction, D ≤ [`ASSERT_MAX_D`].
const MAX_BIAS: f64 = 0.12;

/// One walk: `LEN + 1` lattice points (integer offsets from the start), the continuous start,
/// and `LEN` actions.
struct Walk {
    start: [f32; 2],
    points: Vec<[i32; 2]>,
    actions: Vec<[f32; 2]>,
}

impl Walk {
    fn new(rng: &mut impl Rng) -> Self {
        let start = [rng.gen_range(0.0..10.0f32), rng.gen_range(0.0..10.0f32)];
        let mut p = [0i32, 0];
        let mut points = vec![p];
        let mut actions = Vec::new();
        for _ in 0..LEN {
            let a: [f32; 2] = [rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)];
            p = [p[0] + a[0].round() as i32, p[1] + a[1].round() as i32];
            points.push(p);
            actions.push(a);
        }
        Self {
            start,
            points,
            actions,
        }
    }

    fn state(&self, t: usize) -> [f32; 2] {
        let p = self.points[t];
        [
            (self.start[0] + p[0] as f32) * SCALE,
            (self.start[1] + p[1] as f32) * SCALE,
        ]
    }
}

#[test]
#[cfg_attr(
    debug_assertions,
    ignore = "release only: cargo test --release -p terl-rl --test tep_distance"
)]
fn trained_f_predicts_held_out_step_distances_within_ten_percent() {
    let started = Instant::now();
    let cfg = TepConfig {
        obs_dim: 2,
        act_dim: 2,
        f_hidden: vec![64, 64],
        an_hidden: vec![32, 32],
        f_lr: 3e-4,
        an_lr: 3e-4,
        tau: 0.01,
        batch_size: 512,
        seed: 3,
        ..TepConfig::paper()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let mut buf = TepBuffer::new(200_000, 2, 2);
    for k in 0..4000u64 {
        let w = Walk::new(&mut rng);
        let steps: Vec<u32> = (0..LEN as u32).collect();
        let obs: Vec<f32> = (0..LEN).flat_map(|t| w.state(t)).collect();
        let next: Vec<f32> = (1..=LEN).flat_map(|t| w.state(t)).collect();
        let act: Vec<f32> = w.actions.iter().flatten().copied().collect();
        buf.push_segment(0, k, &steps, &obs, &act, &next).unwrap();
    }
    let mut tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
    let mut batch = TepBatch::with_capacity(cfg.batch_size, 2, 2);
    let updates = 8000;
    for u in 0..updates {
        buf.sample_into(cfg.batch_size, &mut rng, &mut batch)
            .unwrap();
        let st = tep.update(&batch).unwrap();
        if u % 1000 == 0 || u == updates - 1 {
            println!(
                "update {u:5}: F loss {:.4} (step {:.4}, goal {:.4}, sym {:.4}), AN loss {:.3}, \
                 F(s,s') {:.2} vs gap {:.2}",
                st.f_loss,
                st.step_loss,
                st.goal_loss,
                st.symmetry_loss,
                st.an_loss,
                st.goal_distance_mean,
                st.gap_mean
            );
        }
    }

    // Held-out: fresh walks, every pair (s_t, s_{t+k}) with 1 ≤ D ≤ MAX_D, first move towards
    // the goal (0.9 · sign per coordinate).
    let mut planner = tep.planner(1);
    let mut eval = ChaCha8Rng::seed_from_u64(999);
    let mut sum_pred = [0.0f64; MAX_D + 1];
    let mut count = [0usize; MAX_D + 1];
    let (mut rel_sum, mut rel_n) = (0.0f64, 0usize);
    for _ in 0..400 {
        let w = Walk::new(&mut eval);
        for t in 0..LEN {
            for k in t + 1..=LEN {
                let (p, q) = (w.points[t], w.points[k]);
                let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
                let d = dx.abs().max(dy.abs()) as usize;
                if d == 0 || d > MAX_D {
                    continue;
                }
                let toward = |v: i32| 0.9 * v.signum() as f32;
                let a = [toward(dx), toward(dy)];
                let mut out = [0.0f32];
                planner.reach(&w.state(t), &w.state(k), &a, &mut out);
                let f = out[0] as f64;
                sum_pred[d] += f;
                count[d] += 1;
                rel_sum += (f - d as f64).abs() / d as f64;
                rel_n += 1;
            }
        }
    }
    let mut worst = 0.0f64;
    for d in 1..=MAX_D {
        let mean = sum_pred[d] / count[d] as f64;
        let rel = (mean - d as f64) / d as f64;
        if d <= ASSERT_MAX_D {
            worst = worst.max(rel.abs());
        }
        println!(
            "distance {d:2}: mean F = {mean:6.2} ({:+.1} %) over {} pairs",
            100.0 * rel,
            count[d]
        );
    }
    let mare = rel_sum / rel_n as f64;
    println!(
        "held-out: mean |F − d|/d = {:.2} %, worst per-distance bias (D ≤ {ASSERT_MAX_D}) {:.2} %, {:.1} s",
        100.0 * mare,
        100.0 * worst,
        started.elapsed().as_secs_f64()
    );
    assert!(mare < 0.10, "mean relative error {mare}");
    assert!(
        worst < MAX_BIAS,
        "a distance's mean prediction is off by {worst}"
    );
}
