//! TERL guidance: the rule of Eq. 15, its probability σ^N measured empirically, goal states.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_rl::guidance::{
    goal_state, guidance_probability, use_planner, GoalTarget, Guidance, GuidanceConfig,
};

#[test]
fn rule_needs_a_non_improving_step_and_a_draw_below_sigma_pow_n() {
    // First step of an episode: never.
    assert!(!use_planner(5.0, None, 0.0, 0.98, 0));
    // Improving (f_t < f_{t-1}): never, whatever the draw.
    assert!(!use_planner(4.0, Some(5.0), 0.0, 0.98, 0));
    // Not below (equal or worse) and draw < σ^N: guided.
    assert!(use_planner(5.0, Some(5.0), 0.5, 0.98, 0));
    assert!(use_planner(6.0, Some(5.0), 0.5, 0.98, 10)); // 0.98^10 ≈ 0.817
    assert!(!use_planner(6.0, Some(5.0), 0.82, 0.98, 10));
    assert!((guidance_probability(0.98, 10) - 0.98f64.powi(10)).abs() < 1e-15);

    let mut g = Guidance::new(0.98);
    assert!(!g.decide_with_draw(3.0, 0.0)); // no f_{t-1}
    assert!(g.decide_with_draw(3.5, 0.0)); // worse: guided
    assert!(!g.decide_with_draw(3.4, 0.0)); // compared with 3.5 (the policy's f): improving
    g.end_episode();
    assert!(!g.decide_with_draw(9.0, 0.0)); // new episode forgets f_{t-1}
    assert_eq!(g.episodes(), 1);
    assert_eq!(g.counts(), (4, 1));
    assert_eq!(GuidanceConfig::default().sigma, 0.98);
}

#[test]
fn guided_fraction_follows_sigma_pow_n() {
    let draws = 20_000u64;
    // A fixed seed: with 5 checked N at 3σ, about 1 seed in 70 fails by chance (seed 42 does,
    // z = −3.1 at N = 20; seeds 1–7 all stay within |z| < 2.2).
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for n in [0u64, 5, 20, 50, 100, 200] {
        let mut g = Guidance::with_episodes(0.98, n);
        g.decide(0.0, &mut rng); // sets f_{t-1}
        let before = g.counts().1;
        for _ in 0..draws {
            // f never improves, so only the draw decides.
            g.decide(1.0, &mut rng);
        }
        let guided = g.counts().1 - before;
        let p = g.probability();
        let mean = draws as f64 * p;
        let sd = (draws as f64 * p * (1.0 - p)).sqrt();
        let z = if sd > 0.0 {
            (guided as f64 - mean) / sd
        } else {
            0.0
        };
        println!(
            "N = {n:3}: σ^N = {p:.4}, guided {guided}/{draws} = {:.4}, z = {z:+.2}",
            guided as f64 / draws as f64
        );
        if n == 0 {
            assert_eq!(guided, draws);
        } else {
            assert!(
                z.abs() < 3.0,
                "N = {n}: {guided} guided, expected {mean:.1} ± {sd:.1}"
            );
        }
    }
}

#[test]
fn goal_state_replaces_object_or_hand_position_with_the_goal() {
    let obs: Vec<f32> = (0..39).map(|i| i as f32).collect();
    let g = goal_state(&obs, GoalTarget::Object);
    assert_eq!(&g[4..7], &[36.0, 37.0, 38.0]);
    assert_eq!(&g[0..4], &obs[0..4]);
    assert_eq!(&g[7..], &obs[7..]);
    let h = goal_state(&obs, GoalTarget::Hand);
    assert_eq!(&h[0..3], &[36.0, 37.0, 38.0]);
    assert_eq!(&h[3..], &obs[3..]);
    assert_eq!(GoalTarget::for_task("reach-v3"), GoalTarget::Hand);
    assert_eq!(GoalTarget::for_task("pick-place"), GoalTarget::Object);
}
