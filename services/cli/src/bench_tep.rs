//! `terl bench tep`: the TEP update benchmark of `terl_rl::bench_tep` plus the actor-side cost
//! of guidance, which needs real Meta-World environments (hence here, not in `terl-rl`).
//!
//! The actor step is what `terl-actor`'s loop does per step: `Policy::act` on E observations,
//! then `VecEnv::step`. With guidance it also builds E goal states (`goal_state_into`), runs
//! `Planner::reach` on the policy's actions and `Planner::actions` on all E rows, and lets each
//! environment's `Guidance::decide` swap in the planner's action. Both variants run on their own
//! `VecEnv` (same tasks, same seed) in alternating rounds; per-step times and their ratio are
//! medians over rounds, as `terl bench env` does, so background load hits both alike.

use std::time::{Duration, Instant};

use anyhow::Result;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_rl::bench_tep::{median, GuidanceOverhead};
use terl_rl::guidance::{goal_state_into, GoalTarget, Guidance, GuidanceConfig};
use terl_rl::{Planner, Policy, PolicySpec, TepConfig};
use terl_sim::{VecEnv, ACT_DIM, OBS_DIM};

/// Alternating rounds of the with/without measurement.
pub const ROUNDS: usize = 10;

/// The guidance part of one actor: planner, goal states, per-env rule state.
struct Guide {
    planner: Planner,
    targets: Vec<GoalTarget>,
    goals: Vec<f32>,
    reach: Vec<f32>,
    planned: Vec<f32>,
    rules: Vec<Guidance>,
    guided: u64,
    decided: u64,
}

/// One actor's per-step work, optionally guided.
struct ActorLoop {
    env: VecEnv,
    policy: Policy,
    tasks: Vec<usize>,
    obs: Vec<f32>,
    actions: Vec<f32>,
    rng: ChaCha8Rng,
    guide: Option<Guide>,
}

impl ActorLoop {
    fn new(
        all_tasks: &[&'static str],
        num_envs: usize,
        policy_hidden: &[usize],
        planner: Option<&TepConfig>,
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
            act_dim: ACT_DIM,
            num_tasks: all_tasks.len(),
            hidden: policy_hidden.to_vec(),
        };
        let sigma = GuidanceConfig::default().sigma;
        let guide = planner.map(|cfg| Guide {
            planner: Planner::new(cfg, num_envs),
            targets: tasks
                .iter()
                .map(|&t| GoalTarget::for_task(all_tasks[t]))
                .collect(),
            goals: vec![0.0; num_envs * OBS_DIM],
            reach: vec![0.0; num_envs],
            planned: vec![0.0; num_envs * ACT_DIM],
            rules: (0..num_envs).map(|_| Guidance::new(sigma)).collect(),
            guided: 0,
            decided: 0,
        });
        Ok(Self {
            obs: env.obs().to_vec(),
            actions: vec![0.0; num_envs * ACT_DIM],
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
            let rows = self.obs.chunks_exact(OBS_DIM);
            for ((obs, goal), &target) in
                rows.zip(g.goals.chunks_exact_mut(OBS_DIM)).zip(&g.targets)
            {
                goal_state_into(obs, target, goal);
            }
            g.planner
                .reach(&self.obs, &g.goals, &self.actions, &mut g.reach);
            g.planner.actions(&self.obs, &g.goals, &mut g.planned);
            for (i, rule) in g.rules.iter_mut().enumerate() {
                if rule.decide(f64::from(g.reach[i]), &mut self.rng) {
                    let row = i * ACT_DIM..(i + 1) * ACT_DIM;
                    self.actions[row.clone()].copy_from_slice(&g.planned[row]);
                    g.guided += 1;
                }
                g.decided += 1;
            }
        }
        self.env.step(&self.actions)?;
        if let Some(g) = &mut self.guide {
            for end in self.env.finished() {
                g.rules[end.env].end_episode();
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
        planner.obs_dim == OBS_DIM && planner.act_dim == ACT_DIM,
        "guidance needs the Meta-World planner dimensions {OBS_DIM}/{ACT_DIM}"
    );
    let mut without = ActorLoop::new(tasks, num_envs, policy_hidden, None)?;
    let mut with = ActorLoop::new(tasks, num_envs, policy_hidden, Some(planner))?;
    // Warm-up: first steps touch cold caches and code.
    without.run(Duration::from_millis(50))?;
    with.run(Duration::from_millis(50))?;
    let slice = Duration::from_secs_f64(seconds / ROUNDS as f64);
    let (mut t_without, mut t_with, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    for round in 0..ROUNDS {
        // Alternate which variant goes first so neither always follows the other.
        let (a, b) = if round % 2 == 0 {
            let a = without.run(slice)?;
            (a, with.run(slice)?)
        } else {
            let b = with.run(slice)?;
            (without.run(slice)?, b)
        };
        t_without.push(a);
        t_with.push(b);
        ratios.push((b - a) / a);
    }
    let g = with.guide.as_ref().expect("the guided loop has a guide");
    Ok(GuidanceOverhead {
        num_envs,
        tasks: tasks.iter().map(|t| t.to_string()).collect(),
        policy_hidden: policy_hidden.to_vec(),
        rounds: ROUNDS,
        step_us_without: median(t_without),
        step_us_with: median(t_with),
        guidance_overhead_ratio: median(ratios),
        guided_fraction: g.guided as f64 / g.decided.max(1) as f64,
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
