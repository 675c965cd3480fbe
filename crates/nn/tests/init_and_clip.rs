//! Initialisation schemes and global-norm clipping, checked against values computed by hand.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_nn::{clip_global_norm, Activation, Init, Mlp, MlpSpec};

fn spec() -> MlpSpec {
    MlpSpec {
        input: 50,
        hidden: vec![64, 32],
        output: 8,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    }
}

#[test]
fn he_uniform_has_zero_hidden_biases_he_bounds_and_a_small_head() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let net: Mlp<f64> = Mlp::new_with(&spec(), Init::HeUniform { head_bound: 1e-3 }, &mut rng);
    for l in 0..net.num_layers() {
        let fan_in = net.sizes()[l] as f64;
        let w = &net.params[net.weight_range(l)];
        let b = &net.params[net.bias_range(l)];
        if l + 1 < net.num_layers() {
            let bound = (6.0 / fan_in).sqrt();
            assert!(
                b.iter().all(|&v| v == 0.0),
                "hidden bias of layer {l} not zero"
            );
            assert!(w.iter().all(|v| v.abs() < bound));
            // A uniform draw in ±bound has variance bound²/3 = 2/fan_in (He): check it roughly.
            let var = w.iter().map(|v| v * v).sum::<f64>() / w.len() as f64;
            assert!(
                (var * fan_in / 2.0 - 1.0).abs() < 0.15,
                "layer {l}: var {var}"
            );
        } else {
            assert!(w.iter().chain(b).all(|v| v.abs() < 1e-3));
            assert!(w.iter().any(|v| v.abs() > 1e-4), "head is not random");
        }
    }
}

#[test]
fn torch_default_is_what_new_draws() {
    let a: Mlp<f32> = Mlp::new(&spec(), &mut ChaCha8Rng::seed_from_u64(9));
    let b: Mlp<f32> = Mlp::new_with(
        &spec(),
        Init::TorchDefault,
        &mut ChaCha8Rng::seed_from_u64(9),
    );
    assert_eq!(a.params, b.params);
    let bound = 1.0 / (50f32).sqrt();
    let first_bias = &a.params[a.bias_range(0)];
    assert!(first_bias.iter().all(|v| v.abs() < bound) && first_bias.iter().any(|&v| v != 0.0));
}

#[test]
fn global_norm_clipping_scales_all_groups_by_one_factor() {
    // Norm of (3, 4) and (12) is 13.
    let (mut a, mut b) = (vec![3.0f32, 4.0], vec![12.0f32]);
    let norm = clip_global_norm(&mut [&mut a[..], &mut b[..]], 1.0);
    assert!((norm - 13.0).abs() < 1e-9);
    for (got, want) in a
        .iter()
        .chain(&b)
        .zip([3.0 / 13.0, 4.0 / 13.0, 12.0 / 13.0])
    {
        assert!((f64::from(*got) - want).abs() < 1e-7, "{got} vs {want}");
    }
    // Below the bound: untouched, and the norm is still reported.
    let mut c = [0.3f64, 0.4];
    let norm = clip_global_norm(&mut [&mut c[..]], 1.0);
    assert!((norm - 0.5).abs() < 1e-12);
    assert_eq!(c, [0.3, 0.4]);
    // Non-finite: reported, not spread over the other values.
    let mut d = [f64::NAN, 1.0];
    assert!(clip_global_norm(&mut [&mut d[..]], 1.0).is_nan());
    assert_eq!(d[1], 1.0);
}
