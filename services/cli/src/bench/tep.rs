//! `terl bench tep`: the TEP update benchmark of `terl_bench::tep` plus the actor-side cost
//! of guidance, which needs real Meta-World environments (measured here, in the CLI).
//!
//! The actor step is what `terl-actor`'s loop does per step: `Policy::act` on E observations,
//! then `VecEnv::step`. With guidance it also runs `BatchGuidance::apply`, exactly as the actor
//! does: goal states, F on the rows whose decision can need it, Eq. 15, AN on the guided rows.
//! Three variants (without; with at `N = 0`; with after `DECAYED_EPISODES` episodes) run on
//! their own `VecEnv` (same tasks, same seed) in alternating rounds; per-step times and ratios
//! are medians over rounds, as `terl bench env` does, so background load hits all alike.

use std::time::{Duration, Instant};

use anyhow::Result;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_bench::tep::{median, GuidanceOverhead};
use terl_rl::guidance::{guidance_probability, BatchGuidance, GoalTarget, GuidanceConfig};
use terl_rl::{Policy, PolicySpec, Tep, TepConfig};
use terl_sim::{VecEnv, ACTION_DIM, OBS_DIM};

/// Alternating rounds of the guidance measurement.
pub const ROUNDS: usize = 10;

/// Episodes the decayed variant has finished (σ^N = 0.98^100 ≈ 0.13).
pub const DECAYED_EPISODES: u64 = 100;

/// One actor's per-step work, optionally guided.
struct ActorLoop {
    env: VecEnv,
    policy: Policy,
    tasks: Vec<usize>,
    obs: Vec<f32>,
    actions: Vec<f32>,
    rng: ChaCha8Rng,
    guide: Option<BatchGuidance>,
}

impl ActorLoop {
    fn new(
        all_tasks: &[&'static str],
        num_envs: usize,
        policy_hidden: &[usize],
        planner: Option<&TepConfig>,
        episodes: u64,
    ) -> Result<Self> {
        let env = VecEnv::round_robin(all_tasks, num_envs, 3)?;
        let tasks: Vec<usize> = env
            .env_tasks()
            .iter()
            .map(|&k| {
                let name = env.tasks()[k];
                all_tasks
                    .iter()
                    .position(|t| *t == name)
                    .expect("task of the list")
            })
            .collect();
        let spec = PolicySpec {
            obs_dim: OBS_DIM,
            act_dim: ACTION_DIM,
            num_tasks: all_tasks.len(),
            hidden: policy_hidden.to_vec(),
            care: None,
        };
        let sigma = GuidanceConfig::default().sigma;
        let guide = match planner {
            Some(cfg) => {
                let targets = tasks
                    .iter()
                    .map(|&t| GoalTarget::for_task(all_tasks[t]))
                    .collect();
                let mut g = BatchGuidance::new(cfg, sigma, targets).with_episodes(episodes);
                // Real (random) weights with a version, so guidance is active.
                let (f, an) = Tep::<f32>::new(cfg.clone())?.planner_params_f32();
                g.planner_mut().set_params(&f, &an, 1)?;
                Some(g)
            }
            None => None,
        };
        Ok(Self {
            obs: env.obs().to_vec(),
            actions: vec![0.0; num_envs * ACTION_DIM],
            policy: Policy::new(spec, num_envs),
            rng: ChaCha8Rng::seed_from_u64(17),
            env,
            tasks,
            guide,
        })
    }

    fn step(&mut self) -> Result<()> {
        self.policy.act(
            &self.obs,
            &self.tasks,
            false,
            &mut self.rng,
            &mut self.actions,
        )?;
        if let Some(g) = &mut self.guide {
            g.apply(&self.obs, &mut self.actions, &mut self.rng);
        }
        self.env.step(&self.actions)?;
        if let Some(g) = &mut self.guide {
            for end in self.env.finished() {
                g.end_episode(end.env);
            }
        }
        self.obs.copy_from_slice(self.env.obs());
        Ok(())
    }

    /// Steps for `slice`; returns the mean time of one step in µs.
    fn run(&mut self, slice: Duration) -> Result<f64> {
        let (start, mut steps) = (Instant::now(), 0u64);
        while start.elapsed() < slice || steps < 5 {
            for _ in 0..5 {
                self.step()?;
            }
            steps += 5;
        }
        Ok(start.elapsed().as_secs_f64() * 1e6 / steps as f64)
    }
}

/// Actor step time with E environments over `tasks`, with and without guidance, in alternating
/// rounds of `seconds / ROUNDS` each. `planner` gives the planner's network sizes (weights are
/// random: the cost does not depend on them).
pub fn guidance_overhead(
    tasks: &[&'static str],
    num_envs: usize,
    policy_hidden: &[usize],
    planner: &TepConfig,
    seconds: f64,
) -> Result<GuidanceOverhead> {
    anyhow::ensure!(num_envs >= 1, "--envs must be at least 1");
    anyhow::ensure!(
        planner.obs_dim == OBS_DIM && planner.act_dim == ACTION_DIM,
        "guidance needs the Meta-World planner dimensions {OBS_DIM}/{ACTION_DIM}"
    );
    // Without guidance, with it at N = 0, with it after DECAYED_EPISODES episodes.
    let mut actors = [
        ActorLoop::new(tasks, num_envs, policy_hidden, None, 0)?,
        ActorLoop::new(tasks, num_envs, policy_hidden, Some(planner), 0)?,
        ActorLoop::new(
            tasks,
            num_envs,
            policy_hidden,
            Some(planner),
            DECAYED_EPISODES,
        )?,
    ];
    // Warm-up: first steps touch cold caches and code.
    for actor in &mut actors {
        actor.run(Duration::from_millis(50))?;
    }
    let slice = Duration::from_secs_f64(seconds / ROUNDS as f64);
    let mut times: [Vec<f64>; 3] = Default::default();
    let (mut ratios, mut decayed_ratios) = (Vec::new(), Vec::new());
    for round in 0..ROUNDS {
        // Rotate the order so no variant always follows the same one.
        let mut t = [0.0; 3];
        for k in 0..3 {
            let v = (round + k) % 3;
            t[v] = actors[v].run(slice)?;
        }
        for (times, t) in times.iter_mut().zip(t) {
            times.push(t);
        }
        ratios.push((t[1] - t[0]) / t[0]);
        decayed_ratios.push((t[2] - t[0]) / t[0]);
    }
    let fraction = |a: &ActorLoop| {
        let g = a.guide.as_ref().expect("a guided loop has a guide");
        let (decided, _, guided) = g.counts();
        guided as f64 / decided.max(1) as f64
    };
    let [t_without, t_with, t_decayed] = times;
    Ok(GuidanceOverhead {
        num_envs,
        tasks: tasks.iter().map(|t| t.to_string()).collect(),
        policy_hidden: policy_hidden.to_vec(),
        rounds: ROUNDS,
        step_us_without: median(t_without),
        step_us_with: median(t_with),
        guidance_overhead_ratio: median(ratios),
        guided_fraction: fraction(&actors[1]),
        decayed_episodes: DECAYED_EPISODES,
        decayed_probability: guidance_probability(
            GuidanceConfig::default().sigma,
            DECAYED_EPISODES,
        ),
        step_us_with_decayed: median(t_decayed),
        guidance_overhead_ratio_decayed: median(decayed_ratios),
        guided_fraction_decayed: fraction(&actors[2]),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_short_guidance_measurement_is_consistent() {
        let tasks = terl_runtime::resolve_tasks("reach-v3,push-v3").unwrap();
        let planner = TepConfig {
            f_hidden: vec![32, 32],
            an_hidden: vec![32, 32],
            ..TepConfig::default()
        };
        let r = guidance_overhead(&tasks, 2, &[32, 32], &planner, 0.2).unwrap();
        assert_eq!(r.num_envs, 2);
        assert_eq!(r.rounds, ROUNDS);
        assert!(r.step_us_without > 0.0 && r.step_us_with > 0.0);
        assert!(r.guidance_overhead_ratio.is_finite() && r.guidance_overhead_ratio > -1.0);
        assert!((0.0..=1.0).contains(&r.guided_fraction));
        // The first step of an episode is never guided, later ones may be.
        assert!(r.guided_fraction < 1.0);
        assert!(r.step_us_with_decayed > 0.0 && r.guidance_overhead_ratio_decayed > -1.0);
        assert!(r.guided_fraction_decayed < r.guided_fraction.max(1e-9));
        assert!((r.decayed_probability - 0.98f64.powi(100)).abs() < 1e-12);
    }

    #[test]
    fn guidance_rejects_other_dimensions() {
        let tasks = terl_runtime::resolve_tasks("reach-v3").unwrap();
        let planner = TepConfig {
            obs_dim: 10,
            ..TepConfig::default()
        };
        assert!(guidance_overhead(&tasks, 1, &[8], &planner, 0.1).is_err());
        assert!(guidance_overhead(&tasks, 0, &[8], &TepConfig::default(), 0.1).is_err());
    }
}
