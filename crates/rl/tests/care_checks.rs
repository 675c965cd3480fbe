//! CARE ([`terl_rl::care`]) against second paths: every gradient of the update against central
//! finite differences (f64), the attention on the simplex, the inference policy against a
//! forward pass written here from the exported tensors, checkpoint round trips, and the
//! published task context.

mod common;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_nn::gradcheck::max_rel_err;
use terl_nn::tensors::TensorFile;
use terl_rl::care::{self, CareNet};
use terl_rl::{Batch, CareConfig, CareContext, Policy, Sac, SacConfig, UpdateStats};

fn small_care() -> CareConfig {
    CareConfig {
        num_experts: 3,
        expert_hidden: vec![5],
        feature_dim: 4,
        context: CareContext::OneHot,
        context_hidden: vec![6],
        encoding_dim: 3,
        gate_hidden: vec![4],
        temperature: 0.7,
        encoder_tau: 0.05,
    }
}

fn small_config(batch: usize, gamma: f64) -> SacConfig {
    SacConfig {
        obs_dim: 3,
        act_dim: 2,
        num_tasks: 3,
        policy_hidden: vec![8, 8],
        critic_hidden: vec![8, 8],
        batch_size: batch,
        seed: 11,
        gamma,
        initial_log_alpha: -0.5,
        init: terl_rl::NetInit::TorchDefault,
        care: Some(small_care()),
        ..Default::default()
    }
}

/// [`common::random_batch`] with every 4th row terminal.
fn random_batch(rows: usize, cfg: &SacConfig, seed: u64) -> Batch {
    common::random_batch(rows, cfg, seed, 4)
}

/// Central differences of `loss` w.r.t. every parameter of CARE network `net`.
fn numeric(
    sac: &mut Sac<f64>,
    batch: &Batch,
    net: CareNet,
    loss: impl Fn(&UpdateStats) -> f64,
) -> Vec<f64> {
    let h = 1e-6;
    let n = sac.care_net_mut(net).unwrap().params.len();
    (0..n)
        .map(|i| {
            sac.care_net_mut(net).unwrap().params[i] += h;
            let up = loss(&sac.compute_gradients(batch).unwrap());
            sac.care_net_mut(net).unwrap().params[i] -= 2.0 * h;
            let down = loss(&sac.compute_gradients(batch).unwrap());
            sac.care_net_mut(net).unwrap().params[i] += h;
            (up - down) / (2.0 * h)
        })
        .collect()
}

fn check(sac: &mut Sac<f64>, batch: &Batch, net: CareNet, loss: impl Fn(&UpdateStats) -> f64) {
    sac.compute_gradients(batch).unwrap();
    let analytic = sac.care_gradient(net).unwrap().to_vec();
    assert!(
        analytic.iter().any(|g| g.abs() > 1e-9),
        "{net:?}: the gradient is all zeros, the check would prove nothing"
    );
    let num = numeric(sac, batch, net, loss);
    let err = max_rel_err(&analytic, &num);
    assert!(err < 1e-4, "{net:?}: max relative error {err}");
}

/// The encoder's gradients (experts, critics' attention, task encoder from the critics' loss;
/// the actor's attention from the actor's loss). With γ = 0 the critics' target is the reward,
/// so the finite differences see exactly the dependence the update differentiates (the target
/// is a constant of the critics' loss; the actor reads the experts and the task encoding
/// detached).
#[test]
fn encoder_gradients_match_finite_differences() {
    let cfg = small_config(7, 0.0);
    let batch = random_batch(7, &cfg, 3);
    let mut sac: Sac<f64> = Sac::new(cfg).unwrap();
    sac.log_alpha_mut().copy_from_slice(&[-0.7, 0.4, 0.1]);
    sac.resample_noise(batch.len());
    let critics = |s: &UpdateStats| s.qf1_loss + s.qf2_loss;
    for k in 0..3 {
        check(&mut sac, &batch, CareNet::Expert(k), critics);
    }
    check(&mut sac, &batch, CareNet::CriticAttention, critics);
    check(&mut sac, &batch, CareNet::ActorAttention, |s| s.actor_loss);
    // The attention reads the task encoding detached (mtrl's `should_detach_task_encoding`);
    // finite differences see every path, so the task encoder is checked with attention that
    // does not depend on its input (first layer zero: constant, still non-uniform, weights).
    let gate = sac.care_net_mut(CareNet::CriticAttention).unwrap();
    let first = gate.weight_range(0);
    gate.params[first].fill(0.0);
    check(&mut sac, &batch, CareNet::TaskEncoder, critics);
}

/// The heads behind CARE's front, at γ = 0.99 (the target depends on the target copies and
/// the policy, never on the heads' own parameters).
#[test]
fn head_gradients_behind_the_encoder_match_finite_differences() {
    let cfg = small_config(6, 0.99);
    let batch = random_batch(6, &cfg, 4);
    let mut sac: Sac<f64> = Sac::new(cfg).unwrap();
    sac.resample_noise(batch.len());
    sac.compute_gradients(&batch).unwrap();
    let (gp, gq1, _, _) = sac.gradients();
    let (gp, gq1) = (gp.to_vec(), gq1.to_vec());
    let h = 1e-6;
    let mut fd = |which: usize, loss: &dyn Fn(&UpdateStats) -> f64| -> Vec<f64> {
        let n = if which == 0 {
            sac.policy_net().num_params()
        } else {
            sac.critic_net(0).num_params()
        };
        (0..n)
            .map(|i| {
                let bump = |sac: &mut Sac<f64>, d: f64| {
                    if which == 0 {
                        sac.policy_net_mut().params[i] += d;
                    } else {
                        sac.critic_net_mut(0).params[i] += d;
                    }
                };
                bump(&mut sac, h);
                let up = loss(&sac.compute_gradients(&batch).unwrap());
                bump(&mut sac, -2.0 * h);
                let down = loss(&sac.compute_gradients(&batch).unwrap());
                bump(&mut sac, h);
                (up - down) / (2.0 * h)
            })
            .collect()
    };
    let num_q = fd(1, &|s| s.qf1_loss);
    assert!(max_rel_err(&gq1, &num_q) < 1e-4, "critic 1");
    let num_p = fd(0, &|s| s.actor_loss);
    assert!(max_rel_err(&gp, &num_p) < 1e-4, "policy");
}

#[test]
fn attention_rows_are_distributions_and_training_moves_them_apart() {
    let cfg = SacConfig {
        threads: 1,
        ..small_config(32, 0.99)
    };
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let batch = random_batch(32, &cfg, 5);
    sac.update(&batch).unwrap();
    let first: Vec<f32> = sac.care_attention().unwrap().0.to_vec();
    for _ in 0..200 {
        sac.update(&batch).unwrap();
    }
    let (critic, actor) = sac.care_attention().unwrap();
    for w in [critic, actor] {
        assert_eq!(w.len(), 3 * 3);
        for row in w.chunks(3) {
            let sum: f32 = row.iter().sum();
            assert!((sum - 1.0).abs() < 1e-5, "{row:?}");
            assert!(row.iter().all(|&v| v > 0.0 && v < 1.0), "{row:?}");
        }
    }
    assert_ne!(first, critic, "the critics' loss trains the attention");
    assert!(
        critic.chunks(3).any(|r| r != &critic[..3]),
        "tasks attend differently"
    );
}

#[test]
fn the_same_seed_gives_the_same_updates_and_a_checkpoint_resumes_them() {
    let cfg = SacConfig {
        threads: 1,
        ..small_config(16, 0.99)
    };
    let batch = random_batch(16, &cfg, 6);
    let mut a: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let mut b: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    for _ in 0..5 {
        a.update(&batch).unwrap();
        b.update(&batch).unwrap();
    }
    assert_eq!(a.policy_params_f32(), b.policy_params_f32());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("care.safetensors");
    a.save_checkpoint(&path).unwrap();
    let mut c: Sac<f32> = Sac::new(SacConfig {
        seed: 99,
        ..cfg.clone()
    })
    .unwrap();
    assert_ne!(c.policy_params_f32(), a.policy_params_f32());
    c.load_checkpoint(&path).unwrap();
    assert_eq!(c.policy_params_f32(), a.policy_params_f32());
    for _ in 0..3 {
        let sa = a.update(&batch).unwrap();
        let sc = c.update(&batch).unwrap();
        assert_eq!(sa, sc, "a resumed learner continues exactly");
    }
    assert_eq!(c.policy_params_f32(), a.policy_params_f32());
    assert_eq!(c.care_attention(), a.care_attention());

    // An MTSAC checkpoint does not fit a CARE learner, and nothing changes.
    let mtsac: Sac<f32> = Sac::new(SacConfig {
        care: None,
        ..cfg.clone()
    })
    .unwrap();
    let plain = dir.path().join("mtsac.safetensors");
    mtsac.save_checkpoint(&plain).unwrap();
    let before = c.policy_params_f32();
    assert!(c.load_checkpoint(&plain).is_err());
    assert_eq!(c.policy_params_f32(), before);
}

/// A forward pass of one exported MLP (ReLU hidden layers, identity output), f64.
fn mlp(file: &TensorFile, name: &str, x: &[f64]) -> Vec<f64> {
    let mut h = x.to_vec();
    let mut l = 0;
    while let Some(w) = file.tensors.get(&format!("{name}.{l}.weight")) {
        let (out, inp) = (w.shape[0], w.shape[1]);
        let w: Vec<f64> = w
            .values::<f32>()
            .unwrap()
            .into_iter()
            .map(f64::from)
            .collect();
        let b: Vec<f64> = file
            .values::<f32>(&format!("{name}.{l}.bias"), &[out])
            .unwrap()
            .into_iter()
            .map(f64::from)
            .collect();
        assert_eq!(inp, h.len());
        let mut y: Vec<f64> = (0..out)
            .map(|o| b[o] + (0..inp).map(|i| w[o * inp + i] * h[i]).sum::<f64>())
            .collect();
        l += 1;
        let last = !file.tensors.contains_key(&format!("{name}.{l}.weight"));
        if !last {
            y.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        h = y;
    }
    assert!(l > 0, "no tensors named {name}");
    h
}

/// The mean action of CARE's policy written out from the paper's definitions.
fn reference_action(file: &TensorFile, cfg: &CareConfig, obs: &[f64], context: &[f64]) -> Vec<f64> {
    let z = mlp(file, care::names::TASK_ENCODER, context);
    let logits = mlp(file, care::names::ACTOR_GATE, &z);
    let m = logits.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let e: Vec<f64> = logits
        .iter()
        .map(|l| ((l - m) / cfg.temperature).exp())
        .collect();
    let sum: f64 = e.iter().sum();
    let mut h = vec![0.0; cfg.feature_dim];
    for (k, weight) in e.iter().enumerate() {
        let ek = mlp(file, &care::names::expert(k), obs);
        for (hv, v) in h.iter_mut().zip(ek) {
            *hv += weight / sum * v;
        }
    }
    h.extend_from_slice(&z);
    let head = mlp(file, "policy", &h);
    head[..head.len() / 2].iter().map(|m| m.tanh()).collect()
}

#[test]
fn the_inference_policy_matches_a_forward_pass_from_the_exported_tensors() {
    let tasks: Vec<String> = ["reach-v3", "push-v3", "door-open-v3"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for context in [CareContext::OneHot, CareContext::TaskEmbeddings] {
        let cfg = SacConfig {
            care: Some(CareConfig {
                context,
                ..small_care()
            }),
            ..small_config(16, 0.99)
        };
        let mut sac: Sac<f32> = Sac::for_tasks(cfg.clone(), &tasks).unwrap();
        for s in 0..20 {
            sac.update(&random_batch(16, &cfg, s)).unwrap();
        }
        let file = TensorFile::from_tensors(sac.policy_tensors());
        let mut from_flat = Policy::new(sac.policy_spec(), 4);
        from_flat.set_params(&sac.policy_params_f32(), 1).unwrap();
        let mut from_file = Policy::new(sac.policy_spec(), 4);
        from_file.load(&file, 1).unwrap();
        let obs = [0.3f32, -0.1, 0.8, -0.6, 0.2, 0.05, 0.0, 0.9, -0.4];
        let ids = [2usize, 0, 1];
        let (mut a, mut b) = ([0.0f32; 6], [0.0f32; 6]);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        from_flat.act(&obs, &ids, true, &mut rng, &mut a).unwrap();
        from_file.act(&obs, &ids, true, &mut rng, &mut b).unwrap();
        assert_eq!(a, b);
        let table = care::context_table(cfg.care.as_ref().unwrap(), &tasks).unwrap();
        let cd = table.len() / 3;
        let mut rows = Vec::new();
        for (r, &t) in ids.iter().enumerate() {
            let o: Vec<f64> = obs[r * 3..(r + 1) * 3].iter().map(|&v| v as f64).collect();
            let c: Vec<f64> = table[t * cd..(t + 1) * cd]
                .iter()
                .map(|&v| v as f64)
                .collect();
            let want = reference_action(&file, cfg.care.as_ref().unwrap(), &o, &c);
            for (j, w) in want.iter().enumerate() {
                assert!(
                    (a[r * 2 + j] as f64 - w).abs() < 1e-5,
                    "{context:?} row {r}: {a:?} vs {want:?}"
                );
            }
            rows.extend_from_slice(&table[t * cd..(t + 1) * cd]);
            assert_eq!(
                from_flat.care_context(t).unwrap(),
                &table[t * cd..(t + 1) * cd]
            );
        }
        // Explicit context rows (how a task outside the trained list is asked for) give the
        // same actions as the ids of the same rows.
        let mut c = [0.0f32; 6];
        from_flat
            .act_encoded(&obs, &rows, true, &mut rng, &mut c)
            .unwrap();
        assert_eq!(a, c);
        assert!(from_flat
            .act_encoded(&obs, &rows[..cd], true, &mut rng, &mut c)
            .is_err());
        // The spec counts exactly what the learner sends.
        assert_eq!(
            sac.policy_spec().num_params(),
            sac.policy_params_f32().len()
        );
        assert!(from_flat
            .set_params(&sac.policy_params_f32()[1..], 2)
            .is_err());
    }
}

#[test]
fn task_embedding_context_needs_task_names_and_known_tasks() {
    let cfg = SacConfig {
        care: Some(CareConfig::default()),
        ..small_config(8, 0.99)
    };
    let e = Sac::<f32>::new(cfg.clone()).unwrap_err().to_string();
    assert!(e.contains("task names"), "{e}");
    let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let e = Sac::<f32>::for_tasks(cfg.clone(), &names(&["reach-v3", "push-v3", "nope-v3"]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope-v3"), "{e}");
    let e = Sac::<f32>::for_tasks(cfg.clone(), &names(&["reach-v3"]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("num_tasks"), "{e}");
    let bad = SacConfig {
        care: Some(CareConfig {
            temperature: 0.0,
            ..CareConfig::default()
        }),
        ..cfg
    };
    assert!(Sac::<f32>::for_tasks(bad, &names(&["reach-v3", "push-v3", "pick-place-v3"])).is_err());
}
