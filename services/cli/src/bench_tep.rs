//! `terl bench tep`: the TEP update benchmark of `terl_rl::bench_tep` plus the actor-side cost
//! of guidance, which needs real Meta-World environments (hence here, not in `terl-rl`).
//!
//! The actor step is what `terl-actor`'s loop does per step: `Policy::act` on E observations,
//! then `VecEnv::step`. With guidance it also builds E goal states (`goal_state_into`), runs
//! `Planner::reach` on the policy's actions and `Planner::actions` on all E rows, and lets each
//! environment's `Guidance::decide` swap in the planner's action. The variants run on their own
//! `VecEnv` (same tasks, same seed) in alternating rounds; per-step times and their ratio are
//! medians over rounds, as `terl bench env` does, so background load hits both alike.
//!
//! A third variant evaluates `AN` lazily: `Guidance::decide` first (it needs only `F`), then `AN`
//! on just the guided rows, and not at all when no row is guided (the common case once `σ^N`
//! has decayed). Same decisions, same executed actions; only the unused `AN` rows are skipped.

use std::time::{Duration, Instant};

use anyhow::Result;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_rl::bench_tep::{median, GuidanceOverhead};
use terl_rl::guidance::{goal_state_into, GoalTarget, Guidance, GuidanceConfig};
use terl_rl::{Planner, Policy, PolicySpec, TepConfig};
use terl_sim::{VecEnv, ACT_DIM, OBS_DIM};

/// Alternating rounds of the guidance measurement.
pub const ROUNDS: usize = 10;

/// The guidance part of one actor: planner, goal states, per-env rule state.
struct Guide {
    /// Evaluate `AN` only on the rows the rule guides (else on all rows, before deciding).
    lazy: bool,
    /// Rows of the lazy `AN` call: observations, goals, indices.
    lazy_obs: Vec<f32>,
    lazy_goals: Vec<f32>,
    lazy_rows: Vec<usize>,
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
        lazy: bool,
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
            lazy,
            lazy_obs: Vec::with_capacity(num_envs * OBS_DIM),
            lazy_goals: Vec::with_capacity(num_envs * OBS_DIM),
            lazy_rows: Vec::with_capacity(num_envs),
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
            if g.lazy {
                g.lazy_rows.clear();
                for (i, rule) in g.rules.iter_mut().enumerate() {
                    if rule.decide(f64::from(g.reach[i]), &mut self.rng) {
                        g.lazy_rows.push(i);
                    }
                }
                g.decided += g.rules.len() as u64;
                if !g.lazy_rows.is_empty() {
                    g.lazy_obs.clear();
                    g.lazy_goals.clear();
                    for &i in &g.lazy_rows {
                        let row = i * OBS_DIM..(i + 1) * OBS_DIM;
                        g.lazy_obs.extend_from_slice(&self.obs[row.clone()]);
                        g.lazy_goals.extend_from_slice(&g.goals[row]);
                    }
                    let n = g.lazy_rows.len();
                    let planned = &mut g.planned[..n * ACT_DIM];
                    g.planner.actions(&g.lazy_obs, &g.lazy_goals, planned);
                    for (k, &i) in g.lazy_rows.iter().enumerate() {
                        self.actions[i * ACT_DIM..(i + 1) * ACT_DIM]
                            .copy_from_slice(&planned[k * ACT_DIM..(k + 1) * ACT_DIM]);
                    }
                    g.guided += n as u64;
                }
            } else {
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
    // Without guidance, with it, with it and lazy AN.
    let mut actors = [
        ActorLoop::new(tasks, num_envs, policy_hidden, None, false)?,
        ActorLoop::new(tasks, num_envs, policy_hidden, Some(planner), false)?,
        ActorLoop::new(tasks, num_envs, policy_hidden, Some(planner), true)?,
    ];
    // Warm-up: first steps touch cold caches and code.
    for actor in &mut actors {
        actor.run(Duration::from_millis(50))?;
    }
    let slice = Duration::from_secs_f64(seconds / ROUNDS as f64);
    let mut times: [Vec<f64>; 3] = Default::default();
    let (mut ratios, mut lazy_ratios) = (Vec::new(), Vec::new());
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
        lazy_ratios.push((t[2] - t[0]) / t[0]);
    }
    let fraction = |a: &ActorLoop| {
        let g = a.guide.as_ref().expect("a guided loop has a guide");
        g.guided as f64 / g.decided.max(1) as f64
    };
    let [t_without, t_with, t_lazy] = times;
    Ok(GuidanceOverhead {
        num_envs,
        tasks: tasks.iter().map(|t| t.to_string()).collect(),
        policy_hidden: policy_hidden.to_vec(),
        rounds: ROUNDS,
        step_us_without: median(t_without),
        step_us_with: median(t_with),
        guidance_overhead_ratio: median(ratios),
        guided_fraction: fraction(&actors[1]),
        step_us_with_lazy_an: median(t_lazy),
        guidance_overhead_ratio_lazy_an: median(lazy_ratios),
        guided_fraction_lazy_an: fraction(&actors[2]),
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
        assert!(r.step_us_with_lazy_an > 0.0 && r.guidance_overhead_ratio_lazy_an > -1.0);
        assert!((0.0..1.0).contains(&r.guided_fraction_lazy_an));
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
