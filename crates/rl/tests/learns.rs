//! MTSAC and CARE learn the multi-task point mass: ≥ 90 % evaluation success within a step
//! budget (60k env steps for MTSAC; 120k for CARE, whose heads see the tasks only through its
//! attention-weighted experts and task encoding).

use terl_rl::toy::{PointMass, PointMassConfig};
use terl_rl::train::{train, TrainConfig};
use terl_rl::{CareConfig, CareContext, Sac, SacConfig};

#[test]
fn mtsac_solves_three_point_mass_tasks() {
    let env_cfg = PointMassConfig {
        num_tasks: 3,
        envs_per_task: 2,
        ..Default::default()
    };
    let mut env = PointMass::new(env_cfg.clone());
    let mut eval_env = PointMass::new(PointMassConfig {
        envs_per_task: 4,
        ..env_cfg
    });
    let sac_cfg = SacConfig {
        obs_dim: 2,
        act_dim: 2,
        num_tasks: 3,
        policy_hidden: vec![64, 64],
        critic_hidden: vec![64, 64],
        batch_size: 120,
        seed: 1,
        ..Default::default()
    };
    let train_cfg = TrainConfig {
        total_env_steps: 60_000,
        warmup_env_steps: 1_200,
        updates_per_vec_step: 1.0,
        replay_capacity_per_task: 100_000,
        eval_every_env_steps: 3_000,
        eval_episodes_per_env: 5,
        stop_at_eval_success: Some(0.9),
        seed: 2,
        ..Default::default()
    };
    let mut sac = Sac::new(sac_cfg).unwrap();
    let report = train(&mut sac, &mut env, &mut eval_env, &train_cfg, |p, _| {
        let eval = p.eval.as_ref().unwrap();
        eprintln!(
            "steps {:>6} updates {:>6} {:>5.1}s eval success {:.2} {:?} return {:.2} train {:?} stats {:?}",
            p.env_steps, p.updates, p.wall_s, eval.success_rate, eval.per_task_success, eval.mean_return, p.train_success, p.last_update
        );
    })
    .unwrap();
    eprintln!("{report:?}");
    // A step budget, not a time limit (the machine's speed is not what is tested).
    let steps = report
        .reached_target_at_env_steps
        .expect("did not reach 90 % success in 60k env steps");
    assert!(steps <= train_cfg.total_env_steps, "{steps}");
}

#[test]
fn care_solves_three_point_mass_tasks() {
    let env_cfg = PointMassConfig {
        num_tasks: 3,
        envs_per_task: 2,
        ..Default::default()
    };
    let mut env = PointMass::new(env_cfg.clone());
    let mut eval_env = PointMass::new(PointMassConfig {
        envs_per_task: 4,
        ..env_cfg
    });
    let sac_cfg = SacConfig {
        obs_dim: 2,
        act_dim: 2,
        num_tasks: 3,
        policy_hidden: vec![64, 64],
        critic_hidden: vec![64, 64],
        batch_size: 120,
        seed: 1,
        // CARE's published MT10 encoder, on the task one-hot (the toy tasks have no description).
        care: Some(CareConfig {
            context: CareContext::OneHot,
            ..CareConfig::default()
        }),
        ..Default::default()
    };
    let train_cfg = TrainConfig {
        total_env_steps: 120_000,
        warmup_env_steps: 1_200,
        updates_per_vec_step: 1.0,
        replay_capacity_per_task: 100_000,
        eval_every_env_steps: 3_000,
        eval_episodes_per_env: 5,
        stop_at_eval_success: Some(0.9),
        seed: 2,
        ..Default::default()
    };
    let mut sac = Sac::new(sac_cfg).unwrap();
    let mut first_eval = None;
    let report = train(&mut sac, &mut env, &mut eval_env, &train_cfg, |p, _| {
        let eval = p.eval.as_ref().unwrap();
        first_eval.get_or_insert(eval.success_rate);
        eprintln!(
            "steps {:>6} updates {:>6} {:>5.1}s eval success {:.2} {:?} return {:.2}",
            p.env_steps,
            p.updates,
            p.wall_s,
            eval.success_rate,
            eval.per_task_success,
            eval.mean_return
        );
    })
    .unwrap();
    eprintln!("{report:?}");
    assert!(
        report.reached_target_at_wall_s.is_some(),
        "CARE did not reach 90 % success in {} env steps (first evaluation {first_eval:?})",
        train_cfg.total_env_steps
    );
}
