//! The reference MTSAC settings (Meta-World v3 reference implementation): initialisation,
//! Adam ε and global-norm gradient clipping, each checked through a second path (the
//! unclipped gradients of `compute_gradients` and the Adam first-step formula).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_rl::{Batch, NetInit, Sac, SacConfig};

fn config() -> SacConfig {
    SacConfig {
        obs_dim: 5,
        act_dim: 2,
        num_tasks: 3,
        policy_hidden: vec![16, 16],
        critic_hidden: vec![16, 16],
        batch_size: 12,
        seed: 11,
        ..Default::default()
    }
}

fn batch(cfg: &SacConfig) -> Batch {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut b = Batch::with_capacity(cfg.batch_size, cfg.obs_dim, cfg.act_dim);
    for i in 0..cfg.batch_size {
        let obs: Vec<f32> = (0..cfg.obs_dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let next: Vec<f32> = (0..cfg.obs_dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let act: Vec<f32> = (0..cfg.act_dim).map(|_| rng.gen_range(-0.9..0.9)).collect();
        // Large rewards give critic gradients far above a norm of 1.
        let reward = rng.gen_range(-1.0..1.0) * 50.0;
        b.push(&obs, &act, reward, &next, false, (i % cfg.num_tasks) as u32);
    }
    b
}

#[test]
fn defaults_are_the_reference_settings() {
    let c = SacConfig::default();
    assert_eq!(c.policy_hidden, vec![400, 400, 400]);
    assert_eq!(c.critic_hidden, vec![400, 400, 400]);
    assert_eq!(c.adam_eps, 1e-5);
    assert_eq!(c.max_grad_norm, 1.0);
    assert_eq!(c.init, NetInit::HeUniform);
    assert_eq!((c.policy_head_init, c.critic_head_init), (1e-3, 3e-3));
    // And TOML can switch each of them.
    let t = SacConfig::from_toml(
        "adam_eps = 1e-8\nmax_grad_norm = 0.0\ninit = \"torch_default\"\npolicy_head_init = 0.5\n",
    )
    .unwrap();
    assert_eq!(
        (t.adam_eps, t.max_grad_norm, t.init, t.policy_head_init),
        (1e-8, 0.0, NetInit::TorchDefault, 0.5)
    );
    assert!(SacConfig::from_toml("max_grad_norm = -1.0").is_err());
    assert!(SacConfig::from_toml("adam_eps = 0.0").is_err());
    assert!(SacConfig::from_toml("init = \"xavier\"").is_err());
}

#[test]
fn he_uniform_init_gives_zero_hidden_biases_and_small_heads() {
    let sac = Sac::<f32>::new(config()).unwrap();
    let nets = [
        (sac.policy_net(), 1e-3),
        (sac.critic_net(0), 3e-3),
        (sac.critic_net(1), 3e-3),
    ];
    for (net, head) in nets {
        let last = net.num_layers() - 1;
        for l in 0..last {
            assert!(net.params[net.bias_range(l)].iter().all(|&b| b == 0.0));
            let bound = (6.0 / net.sizes()[l] as f32).sqrt();
            assert!(net.params[net.weight_range(l)]
                .iter()
                .all(|w| w.abs() < bound));
        }
        let head_params = net.params[net.weight_range(last)]
            .iter()
            .chain(&net.params[net.bias_range(last)]);
        assert!(head_params.clone().all(|w| f64::from(w.abs()) < head));
    }
    // The two critics are drawn independently; the target starts equal to its critic.
    assert_ne!(sac.critic_net(0).params, sac.critic_net(1).params);
    assert_eq!(sac.critic_net(0).params, sac.target_net(0).params);
    // The old scheme stays available and differs.
    let torch = Sac::<f32>::new(SacConfig {
        init: NetInit::TorchDefault,
        ..config()
    })
    .unwrap();
    assert!(torch.policy_net().params[torch.policy_net().bias_range(0)]
        .iter()
        .any(|&b| b != 0.0));
}

/// The update clips the gradients of `compute_gradients` by the global norm and takes one
/// Adam step with the configured ε: `Δp = −lr·g/(|g| + ε)` on the first step.
fn check_clip_and_adam(max_grad_norm: f64, adam_eps: f64) {
    let cfg = SacConfig {
        max_grad_norm,
        adam_eps,
        ..config()
    };
    let b = batch(&cfg);
    // Same seed, so both draw the same noise: `update` resamples once before computing.
    let mut reference = Sac::<f64>::new(cfg.clone()).unwrap();
    reference.resample_noise(b.len());
    reference.compute_gradients(&b).unwrap();
    let (p_raw, c1_raw, c2_raw, _) = reference.gradients();
    let (p_raw, c1_raw, c2_raw) = (p_raw.to_vec(), c1_raw.to_vec(), c2_raw.to_vec());
    let norm = |gs: &[&[f64]]| {
        gs.iter()
            .flat_map(|g| g.iter())
            .map(|v| v * v)
            .sum::<f64>()
            .sqrt()
    };
    let (actor_norm, critic_norm) = (norm(&[&p_raw]), norm(&[&c1_raw, &c2_raw]));
    assert!(
        critic_norm > 1.0,
        "the test needs critic gradients above the bound"
    );

    let mut sac = Sac::<f64>::new(cfg.clone()).unwrap();
    let before_policy = sac.policy_net().params.clone();
    let before_critic = sac.critic_net(0).params.clone();
    let stats = sac.update(&b).unwrap();
    assert!((stats.actor_grad_norm - actor_norm).abs() <= 1e-9 * actor_norm);
    assert!((stats.critic_grad_norm - critic_norm).abs() <= 1e-9 * critic_norm);

    let scale = |n: f64| {
        if max_grad_norm > 0.0 && n > max_grad_norm {
            max_grad_norm / n
        } else {
            1.0
        }
    };
    let cases = [
        (
            &before_policy,
            &sac.policy_net().params,
            &p_raw,
            scale(actor_norm),
            cfg.actor_lr,
        ),
        (
            &before_critic,
            &sac.critic_net(0).params,
            &c1_raw,
            scale(critic_norm),
            cfg.critic_lr,
        ),
    ];
    for (before, after, raw, s, lr) in cases {
        for i in 0..raw.len() {
            let g = raw[i] * s;
            let want = -lr * g / (g.abs() + adam_eps);
            let got = after[i] - before[i];
            assert!(
                (got - want).abs() <= 1e-9 * lr,
                "param {i}: step {got}, Adam with ε = {adam_eps} and clip scale {s} gives {want}"
            );
        }
    }
}

#[test]
fn updates_clip_the_global_gradient_norm_and_use_the_configured_adam_eps() {
    check_clip_and_adam(1.0, 1e-5);
    // A large ε makes the first Adam step depend on the gradient's size, so this also shows
    // the clip scale reaching the optimiser.
    check_clip_and_adam(1.0, 1e-2);
    check_clip_and_adam(0.0, 1e-2);
}
