//! The selector's value estimates against a second path: a naive dense forward pass over the
//! published tensors (no faer, no caches), so the tensor layout, the one-hot input, the
//! deterministic action and the min over critics are all checked.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_nn::tensors::Tensor;
use terl_rl::ptr::squashed_gaussian_entropy;
use terl_rl::value::ValueEstimator;
use terl_rl::{Sac, SacConfig};

fn config() -> SacConfig {
    SacConfig {
        obs_dim: 7,
        act_dim: 3,
        num_tasks: 4,
        policy_hidden: vec![16, 12],
        critic_hidden: vec![16, 12],
        batch_size: 8,
        ..SacConfig::default()
    }
}

/// `x → layers` with ReLU between layers, from `{prefix}.{l}.weight [out, in]` / bias tensors.
fn naive(tensors: &[Tensor], prefix: &str, x: &[f32]) -> Vec<f64> {
    let mut h: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
    let layers = tensors
        .iter()
        .filter(|t| t.name.starts_with(&format!("{prefix}.")) && t.name.ends_with(".weight"))
        .count();
    for l in 0..layers {
        let find = |n: &str| {
            tensors
                .iter()
                .find(|t| t.name == format!("{prefix}.{l}.{n}"))
                .unwrap()
        };
        let (w, b) = (find("weight"), find("bias"));
        let (out, inp) = (w.shape[0], w.shape[1]);
        let (wv, bv) = (w.values::<f32>().unwrap(), b.values::<f32>().unwrap());
        let mut y = vec![0.0f64; out];
        for o in 0..out {
            let mut s = f64::from(bv[o]);
            for i in 0..inp {
                s += f64::from(wv[o * inp + i]) * h[i];
            }
            y[o] = if l + 1 < layers { s.max(0.0) } else { s };
        }
        h = y;
    }
    h
}

#[test]
fn values_and_entropies_match_a_naive_forward_pass() {
    let cfg = config();
    let sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let mut est = ValueEstimator::new(&cfg, 5);
    assert!(!est.is_ready());
    est.set_policy(&sac.policy_params_f32(), 3).unwrap();
    let critic_flat: Vec<f32> = sac
        .critic_tensors()
        .iter()
        .flat_map(|t| t.values::<f32>().unwrap())
        .collect();
    est.set_critics(&critic_flat, 3).unwrap();
    assert!(est.is_ready());

    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let rows = 13; // not a multiple of max_rows: exercises the chunking
    let obs: Vec<f32> = (0..rows * cfg.obs_dim)
        .map(|_| rng.gen_range(-1.0..1.0))
        .collect();
    let task = 2;
    let (mut v, mut h) = (vec![0.0; rows], vec![0.0; rows]);
    est.evaluate(&obs, task, &mut v, &mut h).unwrap();

    let policy = sac.policy_tensors();
    let critics = sac.critic_tensors();
    for r in 0..rows {
        let o = &obs[r * cfg.obs_dim..(r + 1) * cfg.obs_dim];
        let mut x = o.to_vec();
        x.extend((0..cfg.num_tasks).map(|t| if t == task { 1.0 } else { 0.0 }));
        let head = naive(&policy, "policy", &x);
        let (mean, log_std) = head.split_at(cfg.act_dim);
        let want_h = squashed_gaussian_entropy(
            mean,
            &log_std
                .iter()
                .map(|l| l.clamp(-20.0, 2.0))
                .collect::<Vec<_>>(),
        );
        x.extend(mean.iter().map(|m| m.tanh() as f32));
        let q1 = naive(&critics, "qf1", &x)[0];
        let q2 = naive(&critics, "qf2", &x)[0];
        assert!(
            (v[r] - q1.min(q2)).abs() < 1e-4,
            "row {r}: {} vs {}",
            v[r],
            q1.min(q2)
        );
        assert!(
            (h[r] - want_h).abs() < 1e-4,
            "row {r}: {} vs {want_h}",
            h[r]
        );
    }
}

#[test]
fn bad_weights_and_shapes_are_refused_without_changing_anything() {
    let cfg = config();
    let sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let mut est = ValueEstimator::new(&cfg, 4);
    let mut p = sac.policy_params_f32();
    p.pop();
    assert!(est.set_policy(&p, 1).is_err());
    let mut c: Vec<f32> = sac
        .critic_tensors()
        .iter()
        .flat_map(|t| t.values::<f32>().unwrap())
        .collect();
    c[5] = f32::NAN;
    let e = est.set_critics(&c, 1).unwrap_err().to_string();
    assert!(e.contains("not finite"), "{e}");
    assert!(!est.is_ready());
    let (mut v, mut h) = (vec![0.0; 2], vec![0.0; 2]);
    assert!(est
        .evaluate(&[0.0; 7], 0, &mut v, &mut h)
        .unwrap_err()
        .to_string()
        .contains("evaluate"));
    assert!(est.evaluate(&[0.0; 14], 4, &mut v, &mut h).is_err());
}
