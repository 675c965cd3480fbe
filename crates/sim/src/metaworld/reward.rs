//! Reward shaping primitives of Meta-World v2/v3 rewards (originally from dm_control), with the
//! same numerics as `metaworld/utils/reward_utils.py`.

/// Output of [`tolerance`] at distance `margin` from the bounds unless given otherwise.
pub const DEFAULT_VALUE_AT_MARGIN: f64 = 0.1;

/// The sigmoid used outside the bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sigmoid {
    /// `_sigmoids(x, value_at_1, "gaussian")`: `exp(−(x·s)²/2)` with
    /// `s = sqrt(−2 ln value_at_1)`.
    Gaussian,
    /// `_sigmoids(x, value_at_1, "long_tail")`: `1 / ((x·s)² + 1)` with
    /// `s = sqrt(1/value_at_1 − 1)`.
    LongTail,
}

fn sigmoid(x: f64, value_at_1: f64, kind: Sigmoid) -> f64 {
    match kind {
        Sigmoid::Gaussian => {
            let scale = (-2.0 * value_at_1.ln()).sqrt();
            (-0.5 * (x * scale).powi(2)).exp()
        }
        Sigmoid::LongTail => {
            let scale = (1.0 / value_at_1 - 1.0).sqrt();
            1.0 / ((x * scale).powi(2) + 1.0)
        }
    }
}

/// 1 inside `[lower, upper]`, decaying with the chosen sigmoid outside; `margin` is the distance
/// at which the value is `value_at_margin`. A zero margin gives a hard indicator.
pub fn tolerance_with(
    x: f64,
    (lower, upper): (f64, f64),
    margin: f64,
    kind: Sigmoid,
    value_at_margin: f64,
) -> f64 {
    debug_assert!(lower <= upper);
    let in_bounds = lower <= x && x <= upper;
    if in_bounds {
        return 1.0;
    }
    if margin == 0.0 {
        return 0.0;
    }
    let d = if x < lower { lower - x } else { x - upper } / margin;
    sigmoid(d, value_at_margin, kind)
}

/// `tolerance(d, bounds=(0, radius), margin=abs(d_init - radius), sigmoid=…)`: the
/// `in_place` and `reach` terms of the v3 rewards that measure progress from the start
/// distance `d_init` (e.g. `compute_reward` in `metaworld/envs/sawyer_faucet_open_v3.py`,
/// `sawyer_handle_press_v3.py`, `sawyer_window_open_v3.py`, `sawyer_dial_turn_v3.py`,
/// `sawyer_drawer_close_v3.py`).
pub fn radius_tolerance(d: f64, radius: f64, d_init: f64, kind: Sigmoid) -> f64 {
    tolerance(d, (0.0, radius), (d_init - radius).abs(), kind)
}

/// [`tolerance_with`] at the default value at the margin (0.1).
pub fn tolerance(x: f64, bounds: (f64, f64), margin: f64, kind: Sigmoid) -> f64 {
    tolerance_with(x, bounds, margin, kind, DEFAULT_VALUE_AT_MARGIN)
}

/// Hamacher t-norm: `a*b / (a + b - a*b)`, 0 when both are 0.
pub fn hamacher_product(a: f64, b: f64) -> f64 {
    debug_assert!(
        (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b),
        "{a} {b}"
    );
    let denominator = a + b - a * b;
    if denominator > 0.0 {
        a * b / denominator
    } else {
        0.0
    }
}

/// Python's `rect_prism_tolerance`.
pub fn rect_prism_tolerance(curr: [f64; 3], zero: [f64; 3], one: [f64; 3]) -> f64 {
    let in_range = |a: f64, b: f64, c: f64| {
        if c >= b {
            b <= a && a <= c
        } else {
            c <= a && a <= b
        }
    };
    if (0..3).all(|i| in_range(curr[i], zero[i], one[i])) {
        (0..3)
            .map(|i| (curr[i] - zero[i]) / (one[i] - zero[i]))
            .product()
    } else {
        1.0
    }
}

/// Euclidean norm of `a - b`.
pub fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm(sub(a, b))
}
/// Component-wise `a − b`.
pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
/// Component-wise `a + b`.
pub fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
/// Euclidean norm.
pub fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
/// Norm of the first two components.
pub fn norm2(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1]).sqrt()
}
/// Norm of `(a − b) * scale` (component-wise scaling): the weighted distances the rewards
/// write as `np.linalg.norm((a - b) * scaling)`, e.g. `in_place_scaling` in
/// `metaworld/envs/sawyer_pick_place_wall_v3.py`'s `compute_reward`.
pub fn scaled_dist(a: [f64; 3], b: [f64; 3], scale: [f64; 3]) -> f64 {
    norm([
        (a[0] - b[0]) * scale[0],
        (a[1] - b[1]) * scale[1],
        (a[2] - b[2]) * scale[2],
    ])
}
/// Norm of the x and z components of `a − b`: the `xz` terms of the
/// `_gripper_caging_reward` overrides (`np.linalg.norm(tcp[[0, 2]] - obj[[0, 2]])`, e.g. in
/// `metaworld/envs/sawyer_pick_place_v3.py`).
pub fn dist_xz(a: [f64; 3], b: [f64; 3]) -> f64 {
    dist([a[0], 0.0, a[2]], [b[0], 0.0, b[2]])
}
/// `_reward_quat` of `metaworld/envs/sawyer_assembly_peg_v3.py` (and of box-close, disassemble,
/// hammer): 1 for the object's quaternion (`obs[7..11]`) at `ideal`, falling linearly to 0 at
/// a quaternion error (Euclidean norm) of `zero_at`.
pub fn quat_reward(obs: &[f64], ideal: [f64; 4], zero_at: f64) -> f64 {
    let error = (0..4)
        .map(|i| (obs[7 + i] - ideal[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    (1.0 - error / zero_at).max(0.0)
}
/// Quaternion (x, y, z, w) of a row-major rotation matrix exactly as
/// `scipy.spatial.transform.Rotation.from_matrix(m).as_quat()` computes it (no sign
/// canonicalisation: the branch is `argmax(m00, m11, m22, trace)`, first on ties).
pub fn scipy_quat_from_mat(m: [f64; 9]) -> [f64; 4] {
    let at = |r: usize, c: usize| m[3 * r + c];
    let trace = at(0, 0) + at(1, 1) + at(2, 2);
    let decision = [at(0, 0), at(1, 1), at(2, 2), trace];
    let mut choice = 0;
    for (k, &v) in decision.iter().enumerate() {
        if v > decision[choice] {
            choice = k;
        }
    }
    let mut q = [0.0; 4];
    if choice != 3 {
        let i = choice;
        let j = (i + 1) % 3;
        let k = (j + 1) % 3;
        q[i] = 1.0 - trace + 2.0 * at(i, i);
        q[j] = at(j, i) + at(i, j);
        q[k] = at(k, i) + at(i, k);
        q[3] = at(k, j) - at(j, k);
    } else {
        q[0] = at(2, 1) - at(1, 2);
        q[1] = at(0, 2) - at(2, 0);
        q[2] = at(1, 0) - at(0, 1);
        q[3] = 1.0 + trace;
    }
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tolerance_known_values() {
        // Inside the bounds: exactly 1; at the margin: the value at margin.
        assert_eq!(tolerance(0.02, (0.0, 0.05), 0.3, Sigmoid::LongTail), 1.0);
        let at_margin = tolerance(0.35, (0.0, 0.05), 0.3, Sigmoid::LongTail);
        assert!((at_margin - 0.1).abs() < 1e-12);
        let g = tolerance(1.0, (0.0, 0.0), 1.0, Sigmoid::Gaussian);
        assert!((g - 0.1).abs() < 1e-12);
        assert_eq!(tolerance(0.5, (0.0, 0.1), 0.0, Sigmoid::LongTail), 0.0);
    }

    #[test]
    fn hamacher_is_a_t_norm() {
        assert_eq!(hamacher_product(0.0, 0.0), 0.0);
        assert!((hamacher_product(1.0, 0.3) - 0.3).abs() < 1e-15);
        assert!((hamacher_product(0.5, 0.5) - 1.0 / 3.0).abs() < 1e-15);
    }

    #[test]
    fn scipy_quaternion_round_trips() {
        // Rotation of 90 degrees about z: scipy gives (0, 0, sin 45, cos 45).
        let m = [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        let q = scipy_quat_from_mat(m);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        for (a, b) in q.iter().zip([0.0, 0.0, h, h]) {
            assert!((a - b).abs() < 1e-12, "{q:?}");
        }
        // 180 degrees about x picks the m00 branch: (1, 0, 0, 0).
        let m = [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0];
        assert_eq!(scipy_quat_from_mat(m), [1.0, 0.0, 0.0, 0.0]);
    }
}
