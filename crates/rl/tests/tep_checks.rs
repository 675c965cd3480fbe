//! TEP planner: both losses against finite differences (f64), the loss values against a direct
//! evaluation, hindsight sampling of the buffer, non-finite handling, the update ratio.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_nn::gradcheck::max_rel_err;
use terl_rl::tep::{FTarget, GoalLoss};
use terl_rl::{SacError, Tep, TepBatch, TepBuffer, TepConfig};

fn small_config(batch: usize) -> TepConfig {
    TepConfig {
        obs_dim: 3,
        act_dim: 2,
        f_hidden: vec![8, 7],
        an_hidden: vec![6, 8],
        batch_size: batch,
        tau: 0.1,
        seed: 11,
        ..TepConfig::paper()
    }
}

/// [`small_config`] with each of this implementation's means switched on (the defaults), and
/// with the Monte-Carlo target.
fn variants(batch: usize) -> Vec<(&'static str, TepConfig)> {
    let d = TepConfig::default();
    let means = TepConfig {
        f_target: d.f_target,
        goal_loss: d.goal_loss,
        f_output_scale: 7.0,
        an_bc_weight: 0.8,
        near_goal_fraction: d.near_goal_fraction,
        near_goal_steps: d.near_goal_steps,
        ..small_config(batch)
    };
    vec![
        ("paper", small_config(batch)),
        ("gap_bounded + relative + scale + bc", means.clone()),
        (
            "gap",
            TepConfig {
                f_target: FTarget::Gap,
                ..means
            },
        ),
    ]
}

fn random_batch(rows: usize, cfg: &TepConfig, seed: u64) -> TepBatch {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut b = TepBatch::with_capacity(rows, cfg.obs_dim, cfg.act_dim);
    let mut v = |n: usize, r: f32| -> Vec<f32> { (0..n).map(|_| rng.gen_range(-r..r)).collect() };
    for i in 0..rows {
        let (s, a, s1, g) = (
            v(cfg.obs_dim, 1.5),
            v(cfg.act_dim, 0.9),
            v(cfg.obs_dim, 1.5),
            v(cfg.obs_dim, 1.5),
        );
        b.push(&s, &a, &s1, &g, 2 + i as u32);
    }
    b
}

fn numeric_grad(
    tep: &mut Tep<f64>,
    batch: &TepBatch,
    an: bool,
    loss: impl Fn(&terl_rl::TepStats) -> f64,
) -> Vec<f64> {
    let h = 1e-6;
    let n = if an {
        tep.an_net().num_params()
    } else {
        tep.f_net().num_params()
    };
    (0..n)
        .map(|i| {
            let bump = |t: &mut Tep<f64>, d: f64| {
                if an {
                    t.an_net_mut().params[i] += d
                } else {
                    t.f_net_mut().params[i] += d
                }
            };
            bump(tep, h);
            let up = loss(&tep.compute_gradients(batch).unwrap());
            bump(tep, -2.0 * h);
            let down = loss(&tep.compute_gradients(batch).unwrap());
            bump(tep, h);
            (up - down) / (2.0 * h)
        })
        .collect()
}

/// Moves the targets away from the online nets so the bootstrapped term is not trivially tied.
fn detuned(cfg: TepConfig, batch: &TepBatch) -> Tep<f64> {
    let mut tep: Tep<f64> = Tep::new(cfg).unwrap();
    for _ in 0..3 {
        tep.update(batch).unwrap();
    }
    tep
}

#[test]
fn f_and_an_loss_gradients_match_finite_differences() {
    for (name, cfg) in variants(7) {
        let batch = random_batch(7, &cfg, 3);
        let (c, bc) = (cfg.f_output_scale, cfg.an_bc_weight);
        let mut tep = detuned(cfg, &batch);
        tep.compute_gradients(&batch).unwrap();
        let (gf, gan) = tep.gradients();
        let (gf, gan) = (gf.to_vec(), gan.to_vec());
        assert!(gf.iter().any(|v| v.abs() > 1e-6) && gan.iter().any(|v| v.abs() > 1e-6));

        let num_f = numeric_grad(&mut tep, &batch, false, |s| s.f_loss);
        let ef = max_rel_err(&gf, &num_f);
        // The optimised AN loss: mean F / c + λ · mean ‖AN − a‖².
        let num_an = numeric_grad(&mut tep, &batch, true, |s| {
            s.an_loss / c + bc * s.an_bc_loss
        });
        let ean = max_rel_err(&gan, &num_an);
        println!("{name}: F loss w.r.t. F max rel err {ef:.3e}; AN loss w.r.t. AN {ean:.3e}");
        assert!(ef < 1e-4, "{name}: F loss gradient relative error {ef}");
        assert!(ean < 1e-4, "{name}: AN loss gradient relative error {ean}");
    }
}

/// The stacked evaluation gives the same losses as evaluating each term through the planner
/// (Eq. 13 with the plus, Eq. 14; and the same with each of the means of [`variants`]).
#[test]
fn losses_equal_a_direct_evaluation_of_eq_13_and_14() {
    for (name, cfg) in variants(5) {
        let batch = random_batch(5, &cfg, 8);
        let mut tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
        for _ in 0..4 {
            tep.update(&batch).unwrap();
        }
        let stats = tep.compute_gradients(&batch).unwrap();
        let (od, ad) = (cfg.obs_dim, cfg.act_dim);
        let mut online = tep.planner(8);
        // Target planner: the target weights.
        let mut target = tep.planner(8);
        let tf: Vec<f32> = tep.f_target_net().params.clone();
        let ta: Vec<f32> = tep.an_target_net().params.clone();
        target.set_params(&tf, &ta, 0).unwrap();
        let (mut lf, mut lan, mut lbc) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..batch.len() {
            let s = &batch.obs[i * od..(i + 1) * od];
            let s1 = &batch.next_obs[i * od..(i + 1) * od];
            let g = &batch.goals[i * od..(i + 1) * od];
            let a = &batch.actions[i * ad..(i + 1) * ad];
            let k = f64::from(batch.gaps[i]);
            let neg: Vec<f32> = a.iter().map(|v| -v).collect();
            let mut out = [0.0f32];
            let mut f = |p: &mut terl_rl::Planner, x: &[f32], y: &[f32], u: &[f32]| {
                p.reach(x, y, u, &mut out);
                out[0] as f64
            };
            let mut ta = vec![0.0f32; ad];
            target.actions(s1, g, &mut ta);
            let boot = 1.0 + f(&mut target, s1, g, &ta);
            let z = match cfg.f_target {
                FTarget::Bootstrap => boot,
                FTarget::GapBounded => k.min(boot),
                FTarget::Gap => k,
            };
            let w = match cfg.goal_loss {
                GoalLoss::Squared => 1.0,
                GoalLoss::Relative => 1.0 / z.max(1.0),
            };
            let y1 = f(&mut online, s, s1, a);
            let y2 = f(&mut online, s, g, a);
            let y3 = f(&mut online, s1, s, &neg);
            lf += (y1 - 1.0).powi(2) + w * (y2 - z).powi(2) + (y1 - y3).powi(2);
            let mut an = vec![0.0f32; ad];
            online.actions(s, g, &mut an);
            lan += f(&mut online, s, g, &an);
            lbc += an
                .iter()
                .zip(a)
                .map(|(x, y)| f64::from(x - y).powi(2))
                .sum::<f64>();
        }
        let n = batch.len() as f64;
        for (what, got, want) in [
            ("F loss", stats.f_loss, lf / n),
            ("AN loss", stats.an_loss, lan / n),
            ("AN behaviour cloning", stats.an_bc_loss, lbc / n),
        ] {
            assert!(
                (got - want).abs() < 1e-4 * (1.0 + want.abs()),
                "{name}: {what} {got} vs {want}"
            );
        }
    }
}

#[test]
fn an_loss_leaves_f_alone_and_non_finite_input_changes_nothing() {
    let cfg = small_config(6);
    let batch = random_batch(6, &cfg, 1);
    let mut tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
    let f0 = tep.f_net().params.clone();
    let an0 = tep.an_net().params.clone();
    let mut bad = batch.clone();
    bad.goals[4] = f32::NAN;
    assert!(matches!(
        tep.update(&bad),
        Err(SacError::NonFiniteBatch {
            field: "goals",
            row: 1
        })
    ));
    assert_eq!(tep.rejected_batches(), 1);
    assert_eq!(tep.f_net().params, f0);
    assert_eq!(tep.an_net().params, an0);
    let st = tep.update(&batch).unwrap();
    assert!(st.f_loss.is_finite() && st.an_loss.is_finite());
    assert_eq!(tep.updates(), 1);
    // Non-finite weights give a non-finite loss: stopped, nothing changes.
    tep.f_net_mut().params[0] = f32::INFINITY;
    let before = (tep.f_net().params.clone(), tep.an_net().params.clone());
    assert!(tep.update(&batch).is_err());
    assert_eq!(tep.f_net().params, before.0);
    assert_eq!(tep.an_net().params, before.1);
    assert_eq!(tep.updates(), 1);
}

#[test]
fn buffer_draws_hindsight_goals_from_later_states_of_the_same_segment() {
    let (od, ad) = (2, 1);
    let mut buf = TepBuffer::new(25, od, ad);
    // Trajectory k: obs = [k, step], next = [k, step + 1], steps 0..10.
    for k in 0..4u64 {
        let steps: Vec<u32> = (0..10).collect();
        let obs: Vec<f32> = steps.iter().flat_map(|&s| [k as f32, s as f32]).collect();
        let next: Vec<f32> = steps
            .iter()
            .flat_map(|&s| [k as f32, s as f32 + 1.0])
            .collect();
        let act: Vec<f32> = steps.iter().map(|&s| s as f32).collect();
        buf.push_segment(k as u32, k, &steps, &obs, &act, &next)
            .unwrap();
    }
    assert_eq!(buf.len(), 25);
    assert_eq!(buf.pushed(), 40);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut batch = TepBatch::with_capacity(4000, od, ad);
    buf.sample_into(4000, &mut rng, &mut batch).unwrap();
    let mut trajs = std::collections::BTreeSet::new();
    for i in 0..batch.len() {
        let (k, t) = (batch.obs[2 * i], batch.obs[2 * i + 1]);
        assert_eq!(batch.goals[2 * i], k, "goal from another trajectory");
        assert_eq!(batch.next_obs[2 * i + 1], t + 1.0);
        assert_eq!(batch.actions[i], t);
        let gap = batch.goals[2 * i + 1] - t;
        assert!(gap >= 2.0, "goal not strictly after s_t+1");
        assert_eq!(batch.gaps[i] as f32, gap);
        trajs.insert(k as u32);
        // Oldest 15 transitions are gone: trajectory 0 fully, trajectory 1 up to step 4.
        assert!(k >= 1.0 && !(k == 1.0 && t < 5.0));
        assert!(t < 9.0, "last transition of a segment has no later state");
    }
    assert_eq!(trajs.len(), 3);
    assert!(buf
        .push_segment(0, 9, &[3, 3], &[0.0; 4], &[0.0; 2], &[0.0; 4])
        .is_err());
    let mut lonely = TepBuffer::new(5, od, ad);
    lonely
        .push_segment(0, 0, &[1], &[0.0; 2], &[0.0], &[0.0; 2])
        .unwrap();
    assert!(lonely.sample_into(3, &mut rng, &mut batch).is_err());
}

#[test]
fn config_defaults_toml_and_update_ratio() {
    let d = TepConfig::default();
    assert_eq!((d.f_input(), d.an_input()), (82, 78));
    assert_eq!((d.batch_size, d.buffer_capacity), (1024, 6_000_000));
    assert_eq!(d.f_hidden, vec![512; 3]);
    let c = TepConfig::from_toml("updates_per_sac_update = 0.5\nf_hidden = [64, 64]").unwrap();
    assert_eq!(c.updates_due(10, 0), 5);
    assert_eq!(c.updates_due(11, 5), 0);
    assert_eq!(c.updates_due(12, 5), 1);
    assert!(TepConfig::from_toml("tau = 2.0").is_err());
    assert!(TepConfig::from_toml("nope = 1").is_err());
}

/// F is a step count (Eq. 10: F ≥ 0), so the bootstrapped targets `1 + F̃(..)` are ≥ 1 even when
/// the target network is pushed far below zero: here its output layer is zeroed with a bias of
/// −5 (a linear output would give targets of −4).
#[test]
fn targets_stay_at_least_one_when_the_target_net_outputs_minus_five() {
    let cfg = small_config(6);
    let batch = random_batch(6, &cfg, 21);
    let mut tep: Tep<f64> = Tep::new(cfg.clone()).unwrap();
    let last_hidden = *cfg.f_hidden.last().unwrap();
    let target = tep.f_target_net_mut();
    let n = target.params.len();
    // Layout: … last weight [1, last_hidden], last bias [1].
    for w in &mut target.params[n - 1 - last_hidden..n - 1] {
        *w = 0.0;
    }
    target.params[n - 1] = -5.0;
    let stats = tep.compute_gradients(&batch).unwrap();
    assert!(
        stats.target_min >= 1.0 && stats.target_mean >= 1.0,
        "targets {} (min {})",
        stats.target_mean,
        stats.target_min
    );
    assert!(stats.goal_distance_mean >= 0.0);
    // F itself is ≥ 0 everywhere, also at an online net pushed as far down.
    let online = tep.f_net_mut();
    for w in &mut online.params[n - 1 - last_hidden..n - 1] {
        *w = 0.0;
    }
    online.params[n - 1] = -50.0;
    let mut planner = tep.planner(1);
    let mut out = [0.0f32];
    planner.reach(
        &batch.obs[..3],
        &batch.goals[..3],
        &batch.actions[..2],
        &mut out,
    );
    assert!(out[0] >= 0.0, "F = {}", out[0]);
}

/// A planner restored from its checkpoint tensors continues bit-identically (weights, targets,
/// both optimisers, counters); a planner of another shape refuses them and keeps its weights.
#[test]
fn checkpoint_round_trip_continues_bit_identically() {
    let cfg = small_config(8);
    let mut a: Tep<f32> = Tep::new(cfg.clone()).unwrap();
    for s in 0..4 {
        a.update(&random_batch(8, &cfg, s)).unwrap();
    }
    let file = terl_nn::tensors::TensorFile::from_tensors(a.checkpoint_tensors());
    let mut b: Tep<f32> = Tep::new(TepConfig {
        seed: 99,
        ..cfg.clone()
    })
    .unwrap();
    assert_ne!(a.f_net().params, b.f_net().params);
    b.restore_checkpoint(&file).unwrap();
    assert_eq!(b.updates(), 4);
    for s in 10..13 {
        let (sa, sb) = (
            a.update(&random_batch(8, &cfg, s)).unwrap(),
            b.update(&random_batch(8, &cfg, s)).unwrap(),
        );
        assert_eq!(sa, sb);
    }
    assert_eq!(a.f_net().params, b.f_net().params);
    assert_eq!(a.an_target_net().params, b.an_target_net().params);

    let mut c: Tep<f32> = Tep::new(TepConfig {
        an_hidden: vec![5],
        ..cfg
    })
    .unwrap();
    let before = c.f_net().params.clone();
    let err = c.restore_checkpoint(&file).unwrap_err();
    assert!(err.to_string().contains("tep_an"), "{err}");
    assert_eq!(c.f_net().params, before);
}

/// Network sizes are bounded by their parameter count before anything is allocated: the paper's
/// planner passes, four 16384-wide layers (within the width bound, 800M parameters) do not, and
/// the count matches the layers' weights and biases counted by hand.
#[test]
fn planner_sizes_are_bounded_before_allocation() {
    let paper = TepConfig {
        obs_dim: 39,
        act_dim: 4,
        f_hidden: vec![512; 3],
        an_hidden: vec![512; 3],
        ..TepConfig::default()
    };
    assert!(paper.validate().is_ok());
    // F: 82→512→512→512→1, AN: 78→512→512→512→4.
    let f = 82 * 512 + 512 + 2 * (512 * 512 + 512) + 512 + 1;
    let an = 78 * 512 + 512 + 2 * (512 * 512 + 512) + 512 * 4 + 4;
    assert_eq!(paper.parameters(), f + an);
    let huge = TepConfig {
        f_hidden: vec![16_384; 4],
        ..paper.clone()
    };
    let e = huge.validate().unwrap_err().to_string();
    assert!(e.contains("parameters"), "{e}");
    let wide_input = TepConfig {
        obs_dim: 4_000_000_000,
        ..paper
    };
    assert!(wide_input.validate().is_err());
}
