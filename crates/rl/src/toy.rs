//! A multi-task 2-D point mass: the smallest continuous-control problem on which MTSAC must
//! visibly learn, fast enough for a unit test.
//!
//! The mass starts uniformly in `[-1, 1]²` and moves by `step_size · a` per step (`a ∈ [-1, 1]²`,
//! position clipped to the box). Task `k` has its own goal on a circle of radius 0.6; the
//! observation is the position only, so the policy must read the one-hot task id to know where
//! to go. Reward is `−distance`; success is being within `success_radius` of the goal.
//! Episodes are truncated after `max_steps` (never terminated), like Meta-World's.

use crate::env::{StepBuffers, VecEnvironment};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Sizes and dynamics of the point-mass task family.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PointMassConfig {
    /// Number of tasks, each with its own goal on the circle of radius 0.6.
    pub num_tasks: usize,
    /// Environments per task; environment `i` runs task `i % num_tasks`.
    pub envs_per_task: usize,
    /// Episode length in steps (truncation).
    pub max_steps: usize,
    /// Distance moved per step at full action, per axis.
    pub step_size: f32,
    /// Success distance to the goal.
    pub success_radius: f32,
}

impl Default for PointMassConfig {
    fn default() -> Self {
        Self {
            num_tasks: 3,
            envs_per_task: 2,
            max_steps: 30,
            step_size: 0.1,
            success_radius: 0.1,
        }
    }
}

/// The vectorised point-mass environment.
#[derive(Clone, Debug)]
pub struct PointMass {
    config: PointMassConfig,
    goals: Vec<[f32; 2]>,
    task_ids: Vec<usize>,
    pos: Vec<[f32; 2]>,
    steps: Vec<usize>,
    rng: ChaCha8Rng,
}

impl PointMass {
    /// The `num_tasks · envs_per_task` environments of `config`, all at the origin until
    /// [`VecEnvironment::reset_all`] reseeds the generator and draws their starts; call that
    /// before stepping.
    pub fn new(config: PointMassConfig) -> Self {
        let goals = (0..config.num_tasks)
            .map(|k| {
                let angle = std::f32::consts::TAU * k as f32 / config.num_tasks as f32 + 0.3;
                [0.6 * angle.cos(), 0.6 * angle.sin()]
            })
            .collect();
        let task_ids: Vec<usize> = (0..config.num_tasks * config.envs_per_task)
            .map(|i| i % config.num_tasks)
            .collect();
        let n = task_ids.len();
        Self {
            goals,
            task_ids,
            pos: vec![[0.0; 2]; n],
            steps: vec![0; n],
            rng: ChaCha8Rng::seed_from_u64(0),
            config,
        }
    }

    fn reset_one(&mut self, i: usize) {
        self.pos[i] = [self.rng.gen_range(-1.0..1.0), self.rng.gen_range(-1.0..1.0)];
        self.steps[i] = 0;
    }
}

impl VecEnvironment for PointMass {
    type Error = std::convert::Infallible;

    fn num_envs(&self) -> usize {
        self.task_ids.len()
    }

    fn obs_dim(&self) -> usize {
        2
    }

    fn act_dim(&self) -> usize {
        2
    }

    fn num_tasks(&self) -> usize {
        self.config.num_tasks
    }

    fn task_ids(&self) -> &[usize] {
        &self.task_ids
    }

    fn reset_all(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), Self::Error> {
        self.rng = ChaCha8Rng::seed_from_u64(seed);
        for i in 0..self.num_envs() {
            self.reset_one(i);
            obs[2 * i..2 * i + 2].copy_from_slice(&self.pos[i]);
        }
        Ok(())
    }

    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), Self::Error> {
        let c = self.config.clone();
        for i in 0..self.num_envs() {
            let goal = self.goals[self.task_ids[i]];
            for d in 0..2 {
                let a = actions[2 * i + d].clamp(-1.0, 1.0);
                self.pos[i][d] = (self.pos[i][d] + c.step_size * a).clamp(-1.0, 1.0);
            }
            self.steps[i] += 1;
            let dist =
                ((self.pos[i][0] - goal[0]).powi(2) + (self.pos[i][1] - goal[1]).powi(2)).sqrt();
            out.reward[i] = -dist;
            out.success[i] = dist < c.success_radius;
            out.terminated[i] = false;
            out.truncated[i] = self.steps[i] >= c.max_steps;
            out.final_obs[2 * i..2 * i + 2].copy_from_slice(&self.pos[i]);
            if out.truncated[i] {
                self.reset_one(i);
            }
            out.obs[2 * i..2 * i + 2].copy_from_slice(&self.pos[i]);
        }
        Ok(())
    }
}
