//! The `f32` GEMMs of the instruction set faer chose on this processor (AVX-512 where present,
//! see `InstructionSet::detect`) against a naive `f64` reference, at a learner's shape and with
//! the update's two threads. The small-batch inference kernel is checked on every instruction set
//! the processor has in `terl-rl` (`small_mlp`), where it can be chosen explicitly; faer picks
//! its kernels itself, so this test covers the path this machine runs.

use faer::Par;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_nn::{Activation, InputGrad, InstructionSet, Mlp, MlpCache, MlpSpec};

/// `relu(x·W0ᵀ + b0)·W1ᵀ + b1` and the gradients of `Σ y ⊙ c` w.r.t. W0 and W1, in `f64` loops.
fn reference(net: &Mlp<f32>, x: &[f32], c: &[f64], rows: usize) -> (Vec<f64>, Vec<f64>) {
    let s = net.sizes();
    let (n0, n1, n2) = (s[0], s[1], s[2]);
    let p: Vec<f64> = net.params.iter().map(|&v| f64::from(v)).collect();
    let (w0, b0, w1, b1) = (
        &p[net.weight_range(0)],
        &p[net.bias_range(0)],
        &p[net.weight_range(1)],
        &p[net.bias_range(1)],
    );
    let mut h = vec![0.0; rows * n1];
    let mut y = vec![0.0; rows * n2];
    let mut grads = vec![0.0; p.len()];
    for r in 0..rows {
        for j in 0..n1 {
            let z: f64 = b0[j]
                + (0..n0)
                    .map(|k| f64::from(x[r * n0 + k]) * w0[j * n0 + k])
                    .sum::<f64>();
            h[r * n1 + j] = z.max(0.0);
        }
        for o in 0..n2 {
            y[r * n2 + o] = b1[o] + (0..n1).map(|j| h[r * n1 + j] * w1[o * n1 + j]).sum::<f64>();
        }
        // dL/dy = c; dL/dW1[o][j] += c·h; dL/dh[j] = Σ_o c·W1[o][j] (through the ReLU).
        let (gw0, rest) = grads.split_at_mut(net.bias_range(0).end);
        let gw1 = &mut rest[..n2 * n1];
        for o in 0..n2 {
            for j in 0..n1 {
                gw1[o * n1 + j] += c[r * n2 + o] * h[r * n1 + j];
            }
        }
        for j in 0..n1 {
            if h[r * n1 + j] > 0.0 {
                let dh: f64 = (0..n2).map(|o| c[r * n2 + o] * w1[o * n1 + j]).sum();
                for k in 0..n0 {
                    gw0[j * n0 + k] += dh * f64::from(x[r * n0 + k]);
                }
            }
        }
    }
    (y, grads)
}

#[test]
fn f32_gemms_of_this_instruction_set_match_an_f64_reference() {
    let isa = InstructionSet::detect();
    assert!(isa.is_available());
    let spec = MlpSpec {
        input: 63,
        hidden: vec![400],
        output: 17,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let net: Mlp<f32> = Mlp::new(&spec, &mut rng);
    let rows = 96;
    let x: Vec<f32> = (0..rows * 63).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let c: Vec<f64> = (0..rows * 17).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let (want_y, want_g) = reference(&net, &x, &c, rows);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    for par in [Par::Seq, Par::rayon(2)] {
        let mut cache = MlpCache::new(&net, rows);
        let mut grads = vec![0.0f32; net.num_params()];
        pool.install(|| {
            cache.input_mut(0..rows).copy_from_slice(&x);
            net.forward(&mut cache, rows, par);
            for (d, &v) in cache.grad_output_mut(0..rows).iter_mut().zip(&c) {
                *d = v as f32;
            }
        });
        let y: Vec<f64> = cache
            .output(0..rows)
            .iter()
            .map(|&v| f64::from(v))
            .collect();
        pool.install(|| net.backward(&mut cache, 0..rows, Some(&mut grads), InputGrad::None, par));
        let scale_y = want_y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (a, b) in y.iter().zip(&want_y) {
            assert!(
                (a - b).abs() <= 1e-5 * (1.0 + scale_y),
                "{isa} {par:?}: y {a} vs {b}"
            );
        }
        let weights = [net.weight_range(0), net.weight_range(1)];
        for range in weights {
            let scale = want_g[range.clone()]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            for i in range {
                let (a, b) = (f64::from(grads[i]), want_g[i]);
                assert!(
                    (a - b).abs() <= 1e-4 * (1.0 + scale),
                    "{isa} {par:?}: dW[{i}] {a} vs {b}"
                );
            }
        }
    }
}

/// `forward_rows` over two parts of a batch, at different times, gives each row what one
/// `forward` over all rows gives, within the GEMM's rounding (rows are independent), and leaves
/// the other rows alone.
#[test]
fn forward_over_row_ranges_matches_one_forward() {
    let spec = MlpSpec {
        input: 53,
        hidden: vec![64, 64],
        output: 1,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    };
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let net: Mlp<f32> = Mlp::new(&spec, &mut rng);
    let rows = 40;
    let x: Vec<f32> = (0..rows * 53).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let mut whole = MlpCache::new(&net, rows);
    whole.input_mut(0..rows).copy_from_slice(&x);
    net.forward(&mut whole, rows, Par::Seq);
    let mut parts = MlpCache::new(&net, rows);
    parts.input_mut(0..rows).copy_from_slice(&x);
    net.forward_rows(&mut parts, 0..17, Par::Seq);
    let untouched = parts.output(17..rows).to_vec();
    assert!(
        untouched.iter().all(|&v| v == 0.0),
        "rows 17.. not computed yet"
    );
    net.forward_rows(&mut parts, 17..rows, Par::Seq);
    for (i, (a, b)) in parts
        .output(0..rows)
        .iter()
        .zip(whole.output(0..rows))
        .enumerate()
    {
        assert!(
            (a - b).abs() <= 1e-5 * (1.0 + b.abs()),
            "row {i}: {a} vs {b}"
        );
    }
}
