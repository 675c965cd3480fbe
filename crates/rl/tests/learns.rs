//! MTSAC and CARE learn the multi-task point mass: ≥ 90 % evaluation success within a step
//! budget (60k env steps for MTSAC; 120k for CARE, whose heads see the tasks only through its
//! attention-weighted experts and task encoding).

use terl_rl::toy::{PointMass, PointMassConfig};
use terl_rl::train::{train, TrainConfig, TrainReport};
use terl_rl::{CareConfig, CareContext, Sac, SacConfig};

/// Trains on three point-mass tasks (2 envs each, 64×64 networks) until the evaluation success
/// reaches 90 % or `total_env_steps` are spent; returns the report and the first evaluation's
/// success rate (the untrained policy's).
fn solve_point_mass(care: Option<CareConfig>, total_env_steps: u64) -> (TrainReport, Option<f64>) {
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
        care,
        ..Default::default()
    };
    let train_cfg = TrainConfig {
        total_env_steps,
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
            "steps {:>6} updates {:>6} {:>5.1}s eval success {:.2} {:?} return {:.2} train {:?} stats {:?}",
            p.env_steps, p.updates, p.wall_s, eval.success_rate, eval.per_task_success, eval.mean_return, p.train_success, p.last_update
        );
    })
    .unwrap();
    eprintln!("{report:?}");
    (report, first_eval)
}

#[test]
fn mtsac_solves_three_point_mass_tasks() {
    let budget = 60_000;
    let (report, _) = solve_point_mass(None, budget);
    // A step budget, not a time limit (the machine's speed is not what is tested).
    let steps = report
        .reached_target_at_env_steps
        .expect("did not reach 90 % success in 60k env steps");
    assert!(steps <= budget, "{steps}");
}

#[test]
fn care_solves_three_point_mass_tasks() {
    let budget = 120_000;
    // CARE's published MT10 encoder, on the task one-hot (the toy tasks have no description).
    let care = CareConfig {
        context: CareContext::OneHot,
        ..CareConfig::default()
    };
    let (report, first_eval) = solve_point_mass(Some(care), budget);
    assert!(
        report.reached_target_at_wall_s.is_some(),
        "CARE did not reach 90 % success in {budget} env steps (first evaluation {first_eval:?})"
    );
}
