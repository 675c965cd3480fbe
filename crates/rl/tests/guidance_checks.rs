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
    assert_eq!(&g[22..25], &[36.0, 37.0, 38.0]);
    assert_eq!(&g[0..4], &obs[0..4]);
    assert_eq!(&g[7..22], &obs[7..22]);
    assert_eq!(&g[25..], &obs[25..]);
    let h = goal_state(&obs, GoalTarget::Hand);
    assert_eq!(&h[0..3], &[36.0, 37.0, 38.0]);
    assert_eq!(&h[18..21], &[36.0, 37.0, 38.0]);
    assert_eq!(&h[3..18], &obs[3..18]);
    assert_eq!(&h[21..], &obs[21..]);
    assert_eq!(GoalTarget::for_task("reach-v3"), GoalTarget::Hand);
    assert_eq!(GoalTarget::for_task("pick-place"), GoalTarget::Object);
}

/// The batched actor-side guidance (F only where a decision can use it, AN only on guided
/// rows) decides exactly as the plain rule with F evaluated everywhere and the same draws,
/// and its F work shrinks as σ^N decays.
#[test]
fn batch_guidance_matches_the_plain_rule_and_skips_unneeded_evaluations() {
    use rand::Rng;
    use terl_rl::guidance::{goal_state_into, BatchGuidance};
    use terl_rl::{Tep, TepConfig};

    let (e, od, ad, sigma) = (6usize, 39usize, 4usize, 0.9);
    let cfg = TepConfig {
        f_hidden: vec![32],
        an_hidden: vec![32],
        seed: 5,
        ..TepConfig::default()
    };
    let tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
    let (f, an) = tep.planner_params_f32();
    let targets: Vec<GoalTarget> = (0..e)
        .map(|i| {
            if i % 2 == 0 {
                GoalTarget::Hand
            } else {
                GoalTarget::Object
            }
        })
        .collect();
    // Each environment's own episodes, as the plain per-environment rule counts them.
    let mut batch = BatchGuidance::new(&cfg, sigma, targets.clone())
        .with_counter(terl_rl::guidance::EpisodeCounter::Environment);
    assert_eq!(
        batch.apply(
            &vec![0.0; e * od],
            &mut vec![0.0; e * ad],
            &mut ChaCha8Rng::seed_from_u64(0)
        ),
        0,
        "inactive without weights"
    );
    batch.planner_mut().set_params(&f, &an, 1).unwrap();
    let mut reference = tep.planner(1);
    let mut plain: Vec<Guidance> = (0..e).map(|_| Guidance::new(sigma)).collect();

    // The batch draws one u_t per step, one step ahead: replay that order.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut shadow = ChaCha8Rng::seed_from_u64(11);
    let mut ahead: Option<f64> = None;
    let mut data = ChaCha8Rng::seed_from_u64(3);
    let (mut guided_total, mut f_late) = (0usize, 0u64);
    let mut prev_f: Vec<Option<f64>> = vec![None; e];
    let (mut compared_steps, mut not_improving_steps, mut gap_sum) = (0u64, 0u64, 0.0f64);
    for step in 0..400 {
        let obs: Vec<f32> = (0..e * od).map(|_| data.gen_range(-1.0..1.0)).collect();
        let policy: Vec<f32> = (0..e * ad).map(|_| data.gen_range(-1.0..1.0)).collect();
        let mut actions = policy.clone();
        let (_, f_before, _) = batch.counts();
        let n = batch.apply(&obs, &mut actions, &mut rng);
        guided_total += n;
        if step >= 300 {
            f_late += batch.counts().1 - f_before;
        }
        let u_t = ahead.take().unwrap_or_else(|| shadow.gen());
        ahead = Some(shadow.gen());
        for i in 0..e {
            let o = &obs[i * od..(i + 1) * od];
            let mut g = vec![0.0; od];
            goal_state_into(o, targets[i], &mut g);
            let mut out = [0.0f32];
            reference.reach(o, &g, &policy[i * ad..(i + 1) * ad], &mut out);
            let want = plain[i].decide_with_draw(f64::from(out[0]), u_t);
            assert_eq!(batch.guided()[i], want, "step {step}, env {i}");
            // What the actor stamps on the transition, against the plain rule's own values.
            let told = batch.step(i);
            assert!(told.active);
            assert!((told.probability - plain[i].probability()).abs() < 1e-12);
            if let Some(not_improving) = told.not_improving {
                let prev = prev_f[i].expect("a comparison needs f_{t−1}");
                assert_eq!(not_improving, f64::from(out[0]) >= prev, "step {step}");
                compared_steps += 1;
                not_improving_steps += u64::from(not_improving);
            }
            prev_f[i] = Some(f64::from(out[0]));
            assert_eq!(told.action_gap.is_some(), want, "step {step}, env {i}");
            let row = &actions[i * ad..(i + 1) * ad];
            if want {
                let mut a = [0.0f32; 4];
                reference.actions(o, &g, &mut a);
                for (x, y) in row.iter().zip(a) {
                    assert!((x - y.clamp(-1.0, 1.0)).abs() < 1e-5);
                }
                let gap: f64 = a
                    .iter()
                    .zip(&policy[i * ad..(i + 1) * ad])
                    .map(|(y, p)| f64::from(y.clamp(-1.0, 1.0) - p).powi(2))
                    .sum::<f64>()
                    .sqrt();
                assert!((told.action_gap.unwrap() - gap).abs() < 1e-5);
                gap_sum += gap;
            } else {
                assert_eq!(row, &policy[i * ad..(i + 1) * ad]);
            }
        }
        // Episodes of 10 steps: N grows, σ^N decays (0.9^40 ≈ 0.015 at the end).
        if step % 10 == 9 {
            for (i, rule) in plain.iter_mut().enumerate() {
                batch.end_episode(i);
                rule.end_episode();
                prev_f[i] = None;
            }
        }
    }
    assert!(guided_total > 20, "some steps were guided: {guided_total}");
    // The per-step records add up to the batch's own decision counters.
    let (compared, not_improving, mean_gap) = batch.take_decision_stats();
    assert!(compared > 100, "{compared}");
    assert_eq!(
        (compared, not_improving),
        (compared_steps, not_improving_steps)
    );
    assert!((mean_gap - gap_sum / guided_total as f64).abs() < 1e-6);
    let (decisions, f_rows, an_rows) = batch.counts();
    assert_eq!(decisions, 400 * e as u64);
    assert_eq!(an_rows, guided_total as u64);
    // Late in the run F is needed in only a few steps (p ≈ 0.02–0.05: about 2p of them), and
    // then for every environment (they share the draw and N).
    assert!(
        f_late < 100 * e as u64 / 5,
        "F rows in the last 100 steps: {f_late}"
    );
    assert_eq!(f_late % e as u64, 0);
    assert!(f_rows < decisions);
}

/// The goal state looks like a settled observation: for every goal target, the replaced
/// coordinates agree between the current frame (obs[0..18]) and the previous-frame copy
/// (obs[18..36]), on a real Meta-World layout where the two frames differ.
#[test]
fn goal_state_replaces_both_frames_consistently() {
    use rand::Rng;
    use terl_rl::guidance::FRAME_LEN;
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for target in [GoalTarget::Object, GoalTarget::Hand] {
        for _ in 0..20 {
            let obs: Vec<f32> = (0..39).map(|_| rng.gen_range(-1.0f32..1.0)).collect();
            let g = goal_state(&obs, target);
            let (cur, prev) = (target.range(), target.previous_range());
            assert_eq!(prev.start, cur.start + FRAME_LEN);
            assert_eq!(&g[cur.clone()], &g[prev.clone()], "{target:?}");
            assert_eq!(&g[cur], &obs[36..39]);
            // Everything else is the observation as it was.
            for i in (0..39).filter(|i| !target.range().contains(i) && !prev.contains(i)) {
                assert_eq!(g[i], obs[i], "{target:?} index {i}");
            }
        }
    }
    assert_eq!(GoalTarget::Hand.previous_range(), 18..21);
    assert_eq!(GoalTarget::Object.previous_range(), 22..25);
}

/// σ^N's N: environment 0 finishes 10 episodes. With the actor's counter (the default, the
/// paper's "episodes completed") environment 1's guidance probability is σ^10; with each
/// environment's own counter it stays σ^0 = 1. Episodes before the first planner do not count.
#[test]
fn episode_counter_decides_whose_episodes_decay_guidance() {
    use terl_rl::guidance::{BatchGuidance, EpisodeCounter};
    use terl_rl::{Tep, TepConfig};

    let cfg = TepConfig {
        f_hidden: vec![8],
        an_hidden: vec![8],
        ..TepConfig::default()
    };
    let tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
    let (f, an) = tep.planner_params_f32();
    let sigma = 0.98;
    assert_eq!(
        GuidanceConfig::default().episode_counter,
        EpisodeCounter::Actor
    );
    let decayed = |counter: Option<EpisodeCounter>| {
        let mut g = BatchGuidance::new(&cfg, sigma, vec![GoalTarget::Object; 2]);
        if let Some(c) = counter {
            g = g.with_counter(c);
        }
        g.end_episode(0); // before the planner: not counted
        g.planner_mut().set_params(&f, &an, 1).unwrap();
        for _ in 0..10 {
            g.end_episode(0);
        }
        (g.probability(0), g.probability(1))
    };
    let want = sigma.powi(10);
    for counter in [None, Some(EpisodeCounter::Actor)] {
        let (p0, p1) = decayed(counter);
        assert!(
            (p0 - want).abs() < 1e-12 && (p1 - want).abs() < 1e-12,
            "{p0} {p1}"
        );
    }
    let (p0, p1) = decayed(Some(EpisodeCounter::Environment));
    assert!((p0 - want).abs() < 1e-12, "{p0}");
    assert_eq!(p1, 1.0);
}

/// `[guidance]` accepts the counter choice and the two goal sources; run files written before
/// carry `goal_source = "obs_goal"`, today's `replace`; an unknown source is refused.
#[test]
fn guidance_config_keys() {
    use terl_rl::guidance::{EpisodeCounter, GoalSource};
    let c: GuidanceConfig = toml::from_str("episode_counter = \"environment\"").unwrap();
    assert_eq!(c.episode_counter, EpisodeCounter::Environment);
    assert_eq!(c.sigma, 0.98);
    assert_eq!(c.goal_source, GoalSource::FinalState);
    let old: GuidanceConfig = toml::from_str("goal_source = \"obs_goal\"").unwrap();
    assert_eq!(old.goal_source, GoalSource::Replace);
    assert!(toml::to_string(&old)
        .unwrap()
        .contains("goal_source = \"replace\""));
    assert!(GuidanceConfig {
        min_spearman: 2.0,
        ..c.clone()
    }
    .validate()
    .is_err());
    assert!(GuidanceConfig {
        steps_per_episode: Some(0),
        ..c.clone()
    }
    .validate()
    .is_err());
    assert!(c.validate().is_ok());
    let e = toml::from_str::<GuidanceConfig>("goal_source = \"nearest_successful_final\"")
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown variant"), "{e}");
}

/// The gate: an environment of a task that has not passed the planner check is never guided
/// and its episodes do not count; a task validated later starts at σ^0 = 1. The goal library
/// gives the nearest final state moved onto the episode's goal.
#[test]
fn gate_enables_validated_tasks_and_library_goals_follow_the_episode_goal() {
    use terl_rl::guidance::{BatchGuidance, GoalLibrary, GoalSource};
    use terl_rl::{Tep, TepConfig};
    let (od, ad) = (39usize, 4usize);
    let cfg = TepConfig {
        f_hidden: vec![16],
        an_hidden: vec![16],
        ..TepConfig::default()
    };
    let tep: Tep<f32> = Tep::new(cfg.clone()).unwrap();
    let (f, an) = tep.planner_params_f32();
    let mut g = BatchGuidance::new(&cfg, 0.5, vec![GoalTarget::Object; 2])
        .with_tasks(vec![0, 1])
        .with_goal_source(GoalSource::FinalState);
    g.planner_mut().set_params(&f, &an, 1).unwrap();
    g.set_validated(&[true, false]);
    assert!(g.enabled(0) && !g.enabled(1));
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let obs = vec![0.1f32; 2 * od];
    for _ in 0..200 {
        let mut actions = vec![0.0f32; 2 * ad];
        g.apply(&obs, &mut actions, &mut rng);
        assert!(!g.guided()[1], "an unvalidated task is never guided");
        assert!(actions[ad..].iter().all(|&a| a == 0.0));
    }
    g.end_episode(0);
    g.end_episode(1);
    assert_eq!(g.probability(0), 0.5);
    assert_eq!(g.probability(1), 1.0, "N does not count before validation");
    g.set_validated(&[true, true]);
    assert!(g.enabled(1));
    assert_eq!(g.probability(0), 0.5, "validation latches, N goes on");
    assert_eq!(g.probability(1), 1.0);

    let mut lib = GoalLibrary::new(od);
    let mut near = vec![0.0f32; od];
    near[36..39].copy_from_slice(&[0.1, 0.6, 0.2]);
    near[0..3].copy_from_slice(&[0.1, 0.55, 0.2]);
    near[4..7].copy_from_slice(&[0.1, 0.6, 0.21]);
    let mut far = near.clone();
    far[36..39].copy_from_slice(&[-0.3, 0.9, 0.3]);
    lib.push(0, &far);
    lib.push(0, &near);
    lib.push(1, &far);
    let mut start = vec![0.0f32; od];
    start[36..39].copy_from_slice(&[0.12, 0.62, 0.2]);
    let mut out = vec![0.0f32; od];
    assert!(lib.goal_into(0, &start, &mut out));
    // The nearer state, moved by (0.02, 0.02, 0): hand and object in both frames, goal replaced.
    for (k, d) in [0.02f32, 0.02, 0.0].iter().enumerate() {
        assert!((out[k] - (near[k] + d)).abs() < 1e-6);
        assert!((out[4 + k] - (near[4 + k] + d)).abs() < 1e-6);
        assert!((out[22 + k] - (near[22 + k] + d)).abs() < 1e-6);
        assert_eq!(out[36 + k], start[36 + k]);
    }
    assert!(
        !lib.goal_into(2, &start, &mut out),
        "a task without goal states"
    );
}
