//! An update allocates nothing once the learner is built: SAC and TEP updates (one thread, so
//! every allocation happens on the measured thread) after a warm-up make no heap allocation,
//! counted by a counting global allocator in this test binary.

use terl_rl::tep::TepConfig;
use terl_rl::{Sac, SacConfig, Tep, TepBatch};

#[test]
fn sac_and_tep_updates_allocate_nothing_after_warm_up() {
    // The counter is live in this binary: it sees an allocation.
    let probe = allocation_counter::measure(|| {
        std::hint::black_box(vec![1u8; 64]);
    });
    assert!(probe.count_total > 0);
    let cfg = SacConfig {
        obs_dim: 39,
        act_dim: 4,
        num_tasks: 10,
        policy_hidden: vec![64, 64],
        critic_hidden: vec![64, 64],
        batch_size: 128,
        threads: 1,
        ..SacConfig::default()
    };
    let mut sac: Sac<f32> = Sac::new(cfg.clone()).unwrap();
    let batch = terl_rl::sac::random_batch(&cfg, 1);
    for _ in 0..3 {
        sac.update(&batch).unwrap();
    }
    let info = allocation_counter::measure(|| {
        for _ in 0..5 {
            sac.update(&batch).unwrap();
        }
    });
    assert_eq!(info.count_total, 0, "SAC update allocated: {info:?}");
    assert_eq!(sac.updates(), 8);

    // The same with CARE's encoder in front of the heads.
    let care_cfg = SacConfig {
        care: Some(terl_rl::CareConfig {
            context: terl_rl::CareContext::OneHot,
            ..terl_rl::CareConfig::default()
        }),
        ..cfg.clone()
    };
    let mut care: Sac<f32> = Sac::new(care_cfg).unwrap();
    for _ in 0..3 {
        care.update(&batch).unwrap();
    }
    let info = allocation_counter::measure(|| {
        for _ in 0..5 {
            care.update(&batch).unwrap();
        }
    });
    assert_eq!(info.count_total, 0, "CARE update allocated: {info:?}");

    let tcfg = TepConfig {
        obs_dim: 39,
        act_dim: 4,
        f_hidden: vec![64, 64],
        an_hidden: vec![64, 64],
        batch_size: 128,
        threads: 1,
        ..TepConfig::default()
    };
    let mut tep: Tep<f32> = Tep::new(tcfg.clone()).unwrap();
    let mut tb = TepBatch::with_capacity(128, 39, 4);
    let row: Vec<f32> = (0..39).map(|i| (i as f32 * 0.37).sin()).collect();
    for i in 0..128 {
        let next: Vec<f32> = row.iter().map(|v| v + 0.01 * i as f32).collect();
        tb.push(&row, &[0.1, -0.2, 0.3, 0.0], &next, &next, 2 + i % 5);
    }
    for _ in 0..3 {
        tep.update(&tb).unwrap();
    }
    let info = allocation_counter::measure(|| {
        for _ in 0..5 {
            tep.update(&tb).unwrap();
        }
    });
    assert_eq!(info.count_total, 0, "TEP update allocated: {info:?}");
}
