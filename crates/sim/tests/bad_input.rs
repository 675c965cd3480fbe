//! Bad input gets a clear error and changes nothing; unstable physics resets only that env.

use terl_sim::metaworld::{goal_variations, task_set, Env};
use terl_sim::{SimError, VecEnv};

#[test]
fn unknown_task_lists_valid_names() {
    let err = Env::new("reach-v9").unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, SimError::UnknownTask { .. }), "{msg}");
    assert!(
        msg.contains("reach-v3") && msg.contains("faucet-open-v3"),
        "{msg}"
    );
    let err = task_set("mt11").unwrap_err().to_string();
    assert!(err.contains("mt10"), "{err}");
}

#[test]
fn rand_vec_is_validated() {
    let mut env = Env::new("reach-v3").unwrap();
    let good = goal_variations("reach-v3", 1).unwrap()[0].clone();
    assert!(matches!(
        env.reset(&good[..5]),
        Err(SimError::Length {
            got: 5,
            expected: 6,
            ..
        })
    ));
    let mut nan = good.clone();
    nan[2] = f64::NAN;
    assert!(matches!(
        env.reset(&nan),
        Err(SimError::NonFinite { index: 2, .. })
    ));
    let mut outside = good.clone();
    outside[4] = 5.0;
    assert!(matches!(
        env.reset(&outside),
        Err(SimError::OutOfRange { .. })
    ));
    // Object and goal on top of each other: Python would re-draw forever; we refuse.
    let mut close = good.clone();
    close[0] = -0.05;
    close[1] = 0.7;
    close[3] = -0.05;
    close[4] = 0.8;
    let err = env.reset(&close).unwrap_err().to_string();
    assert!(err.contains("placement rule"), "{err}");
    env.reset(&good).unwrap();
}

#[test]
fn bad_actions_never_reach_the_physics() {
    let mut env = Env::new("reach-v3").unwrap();
    let rv = goal_variations("reach-v3", 1).unwrap()[3].clone();
    let obs0 = env.reset(&rv).unwrap();
    assert!(matches!(
        env.step(&[0.1, 0.2]),
        Err(SimError::Length { .. })
    ));
    assert!(matches!(
        env.step(&[0.1, f32::NAN, 0.0, 0.0]),
        Err(SimError::NonFinite { index: 1, .. })
    ));
    assert!(env.step(&[f32::INFINITY, 0.0, 0.0, 0.0]).is_err());
    assert_eq!(env.steps(), 0, "rejected actions must not count as steps");
    // The same state as a fresh reset: a zero action now matches a twin env stepped once.
    let mut twin = Env::new("reach-v3").unwrap();
    assert_eq!(twin.reset(&rv).unwrap(), obs0);
    let a = env.step(&[0.0; 4]).unwrap();
    let b = twin.step(&[0.0; 4]).unwrap();
    assert_eq!(a, b);

    let mut v = VecEnv::round_robin(&["reach-v3"], 2, 0).unwrap();
    let before = v.obs().to_vec();
    let mut actions = vec![0.5f32; 8];
    actions[6] = f32::NAN;
    assert!(matches!(
        v.step(&actions),
        Err(SimError::NonFinite { index: 6, .. })
    ));
    assert!(v.step(&actions[..4]).is_err());
    assert_eq!(
        v.obs(),
        &before[..],
        "a rejected batch moves no environment"
    );
}

#[test]
fn stepping_past_the_time_limit_is_an_error() {
    let mut env = Env::new("reach-v3").unwrap();
    env.reset(&goal_variations("reach-v3", 2).unwrap()[0])
        .unwrap();
    for t in 1..=500 {
        let s = env.step(&[0.0; 4]).unwrap();
        assert_eq!(s.truncated, t == 500);
    }
    assert!(matches!(
        env.step(&[0.0; 4]),
        Err(SimError::EpisodeOver(500))
    ));
}

#[test]
fn unstable_physics_resets_that_env_and_is_counted() {
    let mut v = VecEnv::round_robin(&["reach-v3"], 2, 0).unwrap();
    v.step(&[0.1; 8]).unwrap();
    v.env_mut(1).inject_nan_velocity();
    v.step(&[0.1; 8]).unwrap();
    assert_eq!(v.instability_events(), 1);
    let ended = v.finished();
    assert_eq!(ended.len(), 1);
    assert_eq!(ended[0].env, 1);
    assert!(ended[0].unstable);
    assert!(v.obs().iter().all(|x| x.is_finite()));
    assert_eq!(v.env(1).steps(), 0, "env 1 was reset");
    assert_eq!(v.env(0).steps(), 2, "env 0 carried on");
    for _ in 0..10 {
        v.step(&[0.1; 8]).unwrap();
    }
    assert_eq!(v.instability_events(), 1);
}

#[test]
fn goal_variations_are_reproducible_and_in_range() {
    for task in ["reach-v3", "faucet-open-v3", "sweep-into-v3"] {
        let a = goal_variations(task, 7).unwrap();
        let b = goal_variations(task, 7).unwrap();
        let c = goal_variations(task, 8).unwrap();
        assert_eq!(a.len(), 50);
        assert_eq!(a, b);
        assert_ne!(a, c);
        let env = Env::new(task).unwrap();
        for rv in &a {
            env.validate_rand_vec(rv).unwrap();
        }
    }
}
