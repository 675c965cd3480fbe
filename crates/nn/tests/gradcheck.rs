//! Finite-difference checks (in f64) of every layer type's backward pass and of the
//! tanh-Gaussian head, plus Adam against a hand-computed step.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_nn::gaussian;
use terl_nn::gradcheck::max_rel_err;
use terl_nn::{Activation, Adam, AdamConfig, InputGrad, Mlp, MlpCache, MlpSpec};

fn spec(act: Activation, out_act: Activation) -> MlpSpec {
    MlpSpec {
        input: 5,
        hidden: vec![7, 6],
        output: 3,
        hidden_activation: act,
        output_activation: out_act,
    }
}

/// `L = Σ c ⊙ f(x)` for fixed random `c`, so `dL/dy = c`.
fn loss(mlp: &Mlp<f64>, x: &[f64], c: &[f64], rows: usize) -> f64 {
    let mut cache = MlpCache::new(mlp, rows);
    cache.input_mut(0..rows).copy_from_slice(x);
    mlp.forward(&mut cache, rows, faer::Par::Seq);
    cache
        .output(0..rows)
        .iter()
        .zip(c)
        .map(|(y, c)| y * c)
        .sum()
}

fn check_layer(act: Activation, out_act: Activation) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mlp: Mlp<f64> = Mlp::new(&spec(act, out_act), &mut rng);
    let rows = 4;
    let x: Vec<f64> = (0..rows * 5).map(|_| rng.gen_range(-1.5..1.5)).collect();
    let c: Vec<f64> = (0..rows * 3).map(|_| rng.gen_range(-1.0..1.0)).collect();

    let mut cache = MlpCache::new(&mlp, rows);
    cache.input_mut(0..rows).copy_from_slice(&x);
    mlp.forward(&mut cache, rows, faer::Par::Seq);
    cache.grad_output_mut(0..rows).copy_from_slice(&c);
    let mut grads = vec![0.0; mlp.num_params()];
    mlp.backward(
        &mut cache,
        0..rows,
        Some(&mut grads),
        InputGrad::All,
        faer::Par::Seq,
    );

    let h = 1e-6;
    let mut numeric = vec![0.0; mlp.num_params()];
    for (i, n) in numeric.iter_mut().enumerate() {
        let mut p = mlp.clone();
        p.params[i] += h;
        let up = loss(&p, &x, &c, rows);
        p.params[i] -= 2.0 * h;
        let down = loss(&p, &x, &c, rows);
        *n = (up - down) / (2.0 * h);
    }
    let e = max_rel_err(&grads, &numeric);
    assert!(
        e < 1e-4,
        "{act:?}/{out_act:?} parameter gradient relative error {e}"
    );

    let mut numeric_x = vec![0.0; x.len()];
    for (i, n) in numeric_x.iter_mut().enumerate() {
        let mut xp = x.clone();
        xp[i] += h;
        let up = loss(&mlp, &xp, &c, rows);
        xp[i] -= 2.0 * h;
        let down = loss(&mlp, &xp, &c, rows);
        *n = (up - down) / (2.0 * h);
    }
    let e = max_rel_err(cache.grad_input(0..rows), &numeric_x);
    assert!(
        e < 1e-4,
        "{act:?}/{out_act:?} input gradient relative error {e}"
    );
}

#[test]
fn identity_layers_match_finite_differences() {
    check_layer(Activation::Identity, Activation::Identity);
}

#[test]
fn relu_layers_match_finite_differences() {
    check_layer(Activation::Relu, Activation::Identity);
}

#[test]
fn tanh_layers_match_finite_differences() {
    check_layer(Activation::Tanh, Activation::Tanh);
}

#[test]
fn softplus_output_matches_finite_differences() {
    check_layer(Activation::Relu, Activation::Softplus);
    check_layer(Activation::Tanh, Activation::Softplus);
}

#[test]
fn backward_over_a_row_range_and_column_subset_matches_full_backward() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mlp: Mlp<f64> = Mlp::new(&spec(Activation::Relu, Activation::Identity), &mut rng);
    let rows = 6;
    let x: Vec<f64> = (0..rows * 5).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let c: Vec<f64> = (0..rows * 3).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let run = |range: std::ops::Range<usize>, ig: InputGrad| {
        let mut cache = MlpCache::new(&mlp, rows);
        cache.input_mut(0..rows).copy_from_slice(&x);
        mlp.forward(&mut cache, rows, faer::Par::Seq);
        cache.grad_output_mut(0..rows).copy_from_slice(&c);
        let mut g = vec![0.0; mlp.num_params()];
        mlp.backward(&mut cache, range.clone(), Some(&mut g), ig, faer::Par::Seq);
        (g, cache.grad_input(range).to_vec())
    };
    // Rows 2..6 of a 6-row forward equal a 4-row forward of those rows.
    let (g_sub, gi_sub) = run(2..6, InputGrad::Cols(3..5));
    let mut cache = MlpCache::new(&mlp, 4);
    cache.input_mut(0..4).copy_from_slice(&x[2 * 5..]);
    mlp.forward(&mut cache, 4, faer::Par::Seq);
    cache.grad_output_mut(0..4).copy_from_slice(&c[2 * 3..]);
    let mut g = vec![0.0; mlp.num_params()];
    mlp.backward(
        &mut cache,
        0..4,
        Some(&mut g),
        InputGrad::All,
        faer::Par::Seq,
    );
    assert!(max_rel_err(&g_sub, &g) < 1e-12);
    for r in 0..4 {
        for col in 3..5 {
            let (a, b) = (gi_sub[r * 5 + col], cache.grad_input(0..4)[r * 5 + col]);
            assert!((a - b).abs() < 1e-12, "row {r} col {col}: {a} vs {b}");
        }
    }
}

/// `L = Σ c ⊙ actions + Σ k ⊙ log_prob` through the reparameterised tanh-Gaussian sample.
#[test]
fn tanh_gaussian_sample_matches_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (rows, a) = (5, 3);
    let mut head: Vec<f64> = (0..rows * 2 * a)
        .map(|_| rng.gen_range(-1.5..1.5))
        .collect();
    // One log-std outside the clamp range: its gradient must be exactly zero.
    head[a] = 3.0;
    let mut eps = vec![0.0; rows * a];
    gaussian::fill_standard_normal(&mut rng, &mut eps);
    let c: Vec<f64> = (0..rows * a).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let k: Vec<f64> = (0..rows).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let loss = |head: &[f64]| {
        let mut act = vec![0.0; rows * a];
        let mut lp = vec![0.0; rows];
        gaussian::sample(head, &eps, a, &mut act, &mut lp);
        act.iter().zip(&c).map(|(x, y)| x * y).sum::<f64>()
            + lp.iter().zip(&k).map(|(x, y)| x * y).sum::<f64>()
    };
    let mut act = vec![0.0; rows * a];
    let mut lp = vec![0.0; rows];
    gaussian::sample(&head, &eps, a, &mut act, &mut lp);
    let mut d_head = vec![0.0; head.len()];
    gaussian::sample_backward(&head, &eps, &act, &c, &k, a, &mut d_head);
    let h = 1e-6;
    let numeric: Vec<f64> = (0..head.len())
        .map(|i| {
            let mut p = head.clone();
            p[i] += h;
            let up = loss(&p);
            p[i] -= 2.0 * h;
            (up - loss(&p)) / (2.0 * h)
        })
        .collect();
    let e = max_rel_err(&d_head, &numeric);
    assert!(e < 1e-4, "tanh-Gaussian relative error {e}");
    assert_eq!(d_head[a], 0.0);
}

#[test]
fn log_prob_matches_the_naive_formula_and_stays_finite_when_saturated() {
    let head = [0.3, -0.5, 0.1, -1.0];
    let eps = [0.7, -1.2];
    let mut act = [0.0; 2];
    let mut lp = [0.0; 1];
    gaussian::sample(&head, &eps, 2, &mut act, &mut lp);
    let mut naive = 0.0;
    for j in 0..2 {
        let std = f64::exp(head[2 + j]);
        let u = head[j] + std * eps[j];
        let normal = -0.5 * eps[j] * eps[j] - head[2 + j] - 0.5 * (2.0 * std::f64::consts::PI).ln();
        naive += normal - (1.0 - u.tanh().powi(2)).ln();
    }
    assert!((lp[0] - naive).abs() < 1e-12, "{} vs {naive}", lp[0]);
    // u = 40: tanh(u) is exactly 1 in floating point but the log-prob must stay finite.
    let head = [40.0f32, 0.0];
    let mut act = [0.0f32];
    let mut lp = [0.0f32];
    gaussian::sample(&head, &[0.0], 1, &mut act, &mut lp);
    assert!(lp[0].is_finite() && act[0] == 1.0);
}

#[test]
fn adam_matches_a_hand_computed_pytorch_step() {
    let cfg = AdamConfig::with_lr(0.1);
    let mut adam = Adam::<f64>::new(2, cfg);
    let mut p = vec![1.0, -2.0];
    adam.step(&mut p, &[0.5, -0.25]);
    // Step 1: m̂ = g, v̂ = g², update = lr · g / (|g| + eps).
    let expect0 = 1.0 - 0.1 * 0.5 / (0.5 + 1e-8);
    assert!((p[0] - expect0).abs() < 1e-12);
    adam.step(&mut p, &[0.5, -0.25]);
    let m = 0.9 * 0.05 + 0.1 * 0.5;
    let v: f64 = 0.999 * (0.001 * 0.25) + 0.001 * 0.25;
    let expect =
        expect0 - (0.1 / (1.0 - 0.81)) * m / (v.sqrt() / (1.0 - 0.999f64 * 0.999).sqrt() + 1e-8);
    assert!((p[0] - expect).abs() < 1e-12, "{} vs {expect}", p[0]);
    assert_eq!(adam.steps(), 2);
}

/// The parameter count computed from a shape is the length of the network built from it, and
/// an overflowing shape is `None`, not a wrapped number.
#[test]
fn parameter_count_of_a_shape_is_the_built_networks() {
    for hidden in [vec![], vec![7], vec![3, 9, 4]] {
        let s = MlpSpec {
            hidden,
            ..spec(Activation::Relu, Activation::Identity)
        };
        let mlp = Mlp::<f64>::new(&s, &mut ChaCha8Rng::seed_from_u64(0));
        assert_eq!(s.checked_num_params(), Some(mlp.num_params()), "{s:?}");
    }
    let huge = MlpSpec {
        input: usize::MAX / 2,
        hidden: vec![4],
        ..spec(Activation::Relu, Activation::Identity)
    };
    assert_eq!(huge.checked_num_params(), None);
}
