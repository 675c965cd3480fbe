//! The SAC losses against finite differences (f64), fixed-seed determinism, bad-input handling,
//! checkpoints and replay sampling.

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_nn::gradcheck::max_rel_err;
use terl_nn::tensors::TensorFile;
use terl_rl::replay::MultiTaskReplay;
use terl_rl::{Batch, Policy, Sac, SacConfig, SacError};

fn small_config(batch: usize) -> SacConfig {
    SacConfig {
        obs_dim: 3,
        act_dim: 2,
        num_tasks: 2,
        policy_hidden: vec![8, 8],
        critic_hidden: vec![8, 8],
        batch_size: batch,
        seed: 5,
        ..Default::default()
    }
}

/// [`common::random_batch`] with every 3rd row terminal.
fn random_batch(rows: usize, cfg: &SacConfig, seed: u64) -> Batch {
    common::random_batch(rows, cfg, seed, 3)
}

/// Central differences of one loss w.r.t. a parameter vector chosen by `params`.
fn numeric_grad(
    sac: &mut Sac<f64>,
    batch: &Batch,
    len: usize,
    params: impl Fn(&mut Sac<f64>) -> &mut [f64],
    loss: impl Fn(&terl_rl::UpdateStats) -> f64,
) -> Vec<f64> {
    let h = 1e-6;
    (0..len)
        .map(|i| {
            params(sac)[i] += h;
            let up = loss(&sac.compute_gradients(batch).unwrap());
            params(sac)[i] -= 2.0 * h;
            let down = loss(&sac.compute_gradients(batch).unwrap());
            params(sac)[i] += h;
            (up - down) / (2.0 * h)
        })
        .collect()
}

#[test]
fn critic_actor_and_temperature_gradients_match_finite_differences() {
    let cfg = SacConfig {
        initial_log_alpha: log_alpha_init_for_test(),
        // PyTorch's init: the reference's ±1e-3 policy head scales the hidden layers'
        // gradients down to where f64 central differences no longer resolve 1e-4 relative
        // error (the backward pass is the same either way).
        init: terl_rl::NetInit::TorchDefault,
        ..small_config(6)
    };
    let batch = random_batch(6, &cfg, 9);
    let mut sac: Sac<f64> = Sac::new(cfg).unwrap();
    // Different temperatures per task so the per-task terms are exercised.
    sac.log_alpha_mut().copy_from_slice(&[-0.7, 0.4]);
    sac.resample_noise(batch.len());
    sac.compute_gradients(&batch).unwrap();
    let (gp, gq1, gq2, ga) = sac.gradients();
    let (gp, gq1, gq2, ga) = (gp.to_vec(), gq1.to_vec(), gq2.to_vec(), ga.to_vec());

    let n = sac.critic_net(0).num_params();
    let num = numeric_grad(
        &mut sac,
        &batch,
        n,
        |s| &mut s.critic_net_mut(0).params,
        |st| st.qf1_loss,
    );
    assert!(
        max_rel_err(&gq1, &num) < 1e-4,
        "critic 1: {}",
        max_rel_err(&gq1, &num)
    );
    let num = numeric_grad(
        &mut sac,
        &batch,
        n,
        |s| &mut s.critic_net_mut(1).params,
        |st| st.qf2_loss,
    );
    assert!(
        max_rel_err(&gq2, &num) < 1e-4,
        "critic 2: {}",
        max_rel_err(&gq2, &num)
    );

    let n = sac.policy_net().num_params();
    let num = numeric_grad(
        &mut sac,
        &batch,
        n,
        |s| &mut s.policy_net_mut().params,
        |st| st.actor_loss,
    );
    assert!(
        max_rel_err(&gp, &num) < 1e-4,
        "actor: {}",
        max_rel_err(&gp, &num)
    );

    let num = numeric_grad(
        &mut sac,
        &batch,
        2,
        |s| s.log_alpha_mut(),
        |st| st.alpha_loss,
    );
    assert!(
        max_rel_err(&ga, &num) < 1e-4,
        "temperature: {}",
        max_rel_err(&ga, &num)
    );
}

fn log_alpha_init_for_test() -> f64 {
    -0.5
}

fn run_updates(seed_batch: u64, n: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>) {
    let cfg = SacConfig {
        threads: 1,
        ..small_config(16)
    };
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let mut replay = MultiTaskReplay::new(cfg.num_tasks, 100, cfg.obs_dim, cfg.act_dim);
    let src = random_batch(64, &cfg, seed_batch);
    for i in 0..src.len() {
        let (o, a) = (cfg.obs_dim, cfg.act_dim);
        replay.push(
            src.task_ids[i] as usize,
            &src.obs[i * o..(i + 1) * o],
            &src.actions[i * a..(i + 1) * a],
            src.rewards[i],
            &src.next_obs[i * o..(i + 1) * o],
            src.terminated[i] > 0.5,
        );
    }
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let mut batch = Batch::with_capacity(16, cfg.obs_dim, cfg.act_dim);
    for _ in 0..n {
        replay.sample_into(16, &mut rng, &mut batch);
        sac.update(&batch).unwrap();
    }
    (
        sac.policy_net().params.clone(),
        sac.critic_net(0).params.clone(),
        sac.target_net(1).params.clone(),
        sac.log_alpha().to_vec(),
    )
}

#[test]
fn two_single_threaded_runs_give_bit_identical_weights() {
    let a = run_updates(1, 50);
    let b = run_updates(1, 50);
    assert!(a
        .0
        .iter()
        .zip(&b.0)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    assert!(a
        .1
        .iter()
        .zip(&b.1)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    assert!(a
        .2
        .iter()
        .zip(&b.2)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    assert!(a
        .3
        .iter()
        .zip(&b.3)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    let c = run_updates(2, 50);
    assert_ne!(a.0, c.0, "different data must give different weights");
}

#[test]
fn non_finite_batches_are_rejected_counted_and_leave_weights_alone() {
    let cfg = small_config(8);
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let before = sac.policy_net().params.clone();
    for (field, value) in [
        ("obs", f32::NAN),
        ("rewards", f32::INFINITY),
        ("next_obs", f32::NEG_INFINITY),
    ] {
        let mut batch = random_batch(8, &cfg, 1);
        match field {
            "obs" => batch.obs[7] = value,
            "rewards" => batch.rewards[3] = value,
            _ => batch.next_obs[0] = value,
        }
        let err = sac.update(&batch).unwrap_err();
        assert!(
            matches!(err, SacError::NonFiniteBatch { field: f, .. } if f == field),
            "{err}"
        );
    }
    assert_eq!(sac.rejected_batches(), 3);
    assert_eq!(sac.updates(), 0);
    assert_eq!(sac.policy_net().params, before);
    // Training continues with the next good batch.
    sac.update(&random_batch(8, &cfg, 2)).unwrap();
    assert_eq!(sac.updates(), 1);
}

#[test]
fn a_non_finite_loss_stops_the_update_and_changes_no_weight() {
    let cfg = small_config(8);
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    // Finite inputs whose squares overflow f32: the critic loss becomes infinite.
    let mut batch = random_batch(8, &cfg, 1);
    batch.rewards.iter_mut().for_each(|r| *r = 3.0e38);
    let snapshot = |s: &Sac<f32>| {
        (
            s.policy_net().params.clone(),
            s.critic_net(0).params.clone(),
            s.target_net(0).params.clone(),
            s.log_alpha().to_vec(),
        )
    };
    let before = snapshot(&sac);
    let err = sac.update(&batch).unwrap_err();
    assert!(matches!(err, SacError::NonFiniteLoss { .. }), "{err}");
    assert!(err.to_string().contains("weights unchanged"));
    assert_eq!(snapshot(&sac), before);
    assert_eq!(sac.updates(), 0);
}

#[test]
fn checkpoint_round_trip_continues_bit_identically() {
    let cfg = small_config(8);
    let mut a: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    for s in 0..5 {
        a.update(&random_batch(8, &cfg, s)).unwrap();
    }
    let dir = std::env::temp_dir().join(format!("terl-rl-ckpt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("sac.safetensors");
    a.save_checkpoint(&path).unwrap();
    let mut b: Sac<f32> = Sac::new(SacConfig {
        seed: 99,
        ..cfg.clone()
    })
    .unwrap();
    b.load_checkpoint(&path).unwrap();
    assert_eq!(b.updates(), 5);
    let (sa, sb) = (
        a.update(&random_batch(8, &cfg, 7)).unwrap(),
        b.update(&random_batch(8, &cfg, 7)).unwrap(),
    );
    assert_eq!(sa, sb);
    assert_eq!(a.policy_net().params, b.policy_net().params);

    // A learner of another shape refuses the file and keeps its weights.
    let mut c: Sac<f32> = Sac::new(SacConfig {
        critic_hidden: vec![16, 8],
        ..cfg
    })
    .unwrap();
    let before = c.critic_net(0).params.clone();
    let err = c.load_checkpoint(&path).unwrap_err();
    assert!(err.to_string().contains("qf1.0.weight"), "{err}");
    assert_eq!(c.critic_net(0).params, before);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn exported_policy_weights_drive_an_inference_policy() {
    let cfg = small_config(8);
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    sac.update(&random_batch(8, &cfg, 1)).unwrap();
    let obs = [0.1, -0.2, 0.3, 0.5, 0.0, -0.5];
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut from_flat = Policy::new(sac.policy_spec(), 8);
    from_flat
        .set_params(&sac.policy_params_f32(), sac.updates())
        .unwrap();
    let mut a1 = [0.0; 4];
    from_flat
        .act(&obs, &[0, 1], true, &mut rng, &mut a1)
        .unwrap();
    let mut from_tensors = Policy::new(sac.policy_spec(), 8);
    from_tensors
        .load(&TensorFile::from_tensors(sac.policy_tensors()), 1)
        .unwrap();
    let mut a2 = [0.0; 4];
    from_tensors
        .act(&obs, &[0, 1], true, &mut rng, &mut a2)
        .unwrap();
    assert_eq!(a1, a2);
    assert!(a1.iter().all(|a| a.abs() < 1.0));
    let mut a3 = [0.0; 4];
    from_tensors
        .act(&obs, &[0, 1], false, &mut rng, &mut a3)
        .unwrap();
    assert_ne!(a1, a3, "stochastic actions differ from the mean action");
    assert!(from_flat.set_params(&[0.0; 3], 0).is_err());
    assert!(from_flat
        .act(&obs, &[0, 2], true, &mut rng, &mut a1)
        .is_err());
}

#[test]
fn replay_batches_split_evenly_across_tasks() {
    let mut replay = MultiTaskReplay::new(3, 10, 1, 1);
    for t in 0..3 {
        for i in 0..(5 + t) {
            replay.push(t, &[i as f32], &[0.0], 0.0, &[0.0], false);
        }
    }
    let mut batch = Batch::with_capacity(10, 1, 1);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut counts = [0usize; 3];
    for _ in 0..3 {
        replay.sample_into(10, &mut rng, &mut batch);
        assert_eq!(batch.len(), 10);
        let per: Vec<usize> = (0..3)
            .map(|t| batch.task_ids.iter().filter(|&&x| x == t).count())
            .collect();
        assert!(per.iter().all(|&c| c == 3 || c == 4), "{per:?}");
        (0..3).for_each(|t| counts[t] += per[t]);
    }
    assert_eq!(
        counts,
        [10, 10, 10],
        "the leftover row rotates between tasks"
    );
    let cap = batch.obs.capacity();
    replay.sample_into(10, &mut rng, &mut batch);
    assert_eq!(
        batch.obs.capacity(),
        cap,
        "sampling reuses the batch storage"
    );
    // Ring buffer: the oldest transitions are overwritten.
    for i in 0..25 {
        replay.push(0, &[100.0 + i as f32], &[0.0], 0.0, &[0.0], false);
    }
    assert_eq!(replay.task(0).len(), 10);
}

#[test]
fn config_round_trips_through_toml_and_rejects_unknown_keys() {
    let cfg = SacConfig {
        num_tasks: 10,
        batch_size: 256,
        ..Default::default()
    };
    assert_eq!(SacConfig::from_toml(&cfg.to_toml()).unwrap(), cfg);
    let partial = SacConfig::from_toml("num_tasks = 3\ncritic_hidden = [64, 64]\n").unwrap();
    assert_eq!(partial.num_tasks, 3);
    assert_eq!(partial.tau, 0.005);
    assert!(SacConfig::from_toml("batchsize = 3").is_err());
}

#[test]
fn terminal_transitions_do_not_bootstrap_but_truncated_ones_do() {
    let cfg = small_config(8);
    let loss_with = |terminated: f32, next_shift: f32| {
        let mut sac: Sac<f64> = Sac::new(cfg.clone()).unwrap();
        let mut batch = random_batch(8, &cfg, 4);
        batch.terminated.iter_mut().for_each(|t| *t = terminated);
        batch.next_obs.iter_mut().for_each(|o| *o += next_shift);
        sac.resample_noise(8);
        sac.compute_gradients(&batch).unwrap().qf1_loss
    };
    // Terminal: the target is the reward alone, whatever the next observation.
    assert_eq!(loss_with(1.0, 0.0), loss_with(1.0, 5.0));
    // Not terminal (e.g. a time-limit truncation): the next observation matters.
    assert_ne!(loss_with(0.0, 0.0), loss_with(0.0, 5.0));
}

#[test]
fn inference_policy_matches_the_training_network() {
    let cfg = SacConfig {
        obs_dim: 5,
        policy_hidden: vec![40, 24],
        num_tasks: 3,
        ..small_config(8)
    };
    let sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let net = sac.policy_net();
    let rows = 7;
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let obs: Vec<f32> = (0..rows * 5).map(|_| rng.gen_range(-2.0..2.0)).collect();
    let tasks: Vec<usize> = (0..rows).map(|i| i % 3).collect();
    let mut cache = terl_nn::MlpCache::new(net, rows);
    let input = cache.input_mut(0..rows);
    for r in 0..rows {
        input[r * 8..r * 8 + 5].copy_from_slice(&obs[r * 5..(r + 1) * 5]);
        input[r * 8 + 5..(r + 1) * 8].fill(0.0);
        input[r * 8 + 5 + tasks[r]] = 1.0;
    }
    net.forward(&mut cache, rows, faer::Par::Seq);
    let mut expected = vec![0.0; rows * 2];
    terl_nn::gaussian::mean_action(cache.output(0..rows), 2, &mut expected);
    let mut policy = Policy::new(sac.policy_spec(), 8);
    policy.set_params(&sac.policy_params_f32(), 0).unwrap();
    let mut actions = vec![0.0; rows * 2];
    policy
        .act(&obs, &tasks, true, &mut rng, &mut actions)
        .unwrap();
    for (a, e) in actions.iter().zip(&expected) {
        assert!((a - e).abs() < 1e-5, "{a} vs {e}");
    }
}

#[test]
fn two_threads_compute_the_same_update_as_one() {
    let run = |threads: usize| {
        let cfg = SacConfig {
            threads,
            policy_hidden: vec![64, 64],
            critic_hidden: vec![64, 64],
            ..small_config(48)
        };
        let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
        for s in 0..5 {
            sac.update(&random_batch(48, &cfg, s)).unwrap();
        }
        (
            sac.policy_net().params.clone(),
            sac.critic_net(1).params.clone(),
            sac.log_alpha().to_vec(),
        )
    };
    let (one, two) = (run(1), run(2));
    let close = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= 1e-5 * (1.0 + x.abs()))
    };
    assert!(close(&one.0, &two.0) && close(&one.1, &two.1) && close(&one.2, &two.2));
}

/// `random_batch` fills every row with finite values spread over the tasks, and
/// `standalone_update_rate` agrees with timing the same updates by hand (a second path; the
/// bound is a factor of 10 because other tests share the machine, loose enough for load and
/// tight enough to catch a wrong unit or count) and refuses an invalid config.
#[test]
fn standalone_update_rate_agrees_with_hand_timed_updates() {
    let cfg = SacConfig {
        policy_hidden: vec![64, 64],
        critic_hidden: vec![64, 64],
        ..small_config(128)
    };
    let batch = terl_rl::sac::random_batch(&cfg, 3);
    assert_eq!(batch.len(), 128);
    batch.check_finite().unwrap();
    batch.check_shape(cfg.num_tasks).unwrap();
    assert!((0..cfg.num_tasks as u32).all(|t| batch.task_ids.contains(&t)));

    let rate = terl_rl::sac::standalone_update_rate(&cfg, 0.3).unwrap();
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    sac.update(&batch).unwrap();
    let start = std::time::Instant::now();
    let mut n = 0;
    while start.elapsed().as_secs_f64() < 0.3 {
        sac.update(&batch).unwrap();
        n += 1;
    }
    let by_hand = f64::from(n) / start.elapsed().as_secs_f64();
    assert!(
        rate > by_hand / 10.0 && rate < by_hand * 10.0,
        "standalone {rate:.1}/s vs by hand {by_hand:.1}/s"
    );
    // Zero seconds times the warm-up update alone.
    assert!(terl_rl::sac::standalone_update_rate(&cfg, 0.0).unwrap() > 0.0);
    let bad = SacConfig {
        batch_size: 0,
        ..cfg
    };
    assert!(terl_rl::sac::standalone_update_rate(&bad, 0.1).is_err());
}
