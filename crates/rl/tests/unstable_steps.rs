//! Steps cut short by a physics blow-up are not learned as transitions: the trainer drops and
//! counts them. The environment seam is wrapped so that every 7th step of environment 0 is
//! "unstable" with a non-finite next observation, as a blown-up simulator would give before
//! clean-up: stored, it would poison every batch that samples it.

use terl_rl::env::{StepBuffers, VecEnvironment};
use terl_rl::toy::{PointMass, PointMassConfig};
use terl_rl::train::{train, TrainConfig};
use terl_rl::{Sac, SacConfig};

struct BlowsUp {
    inner: PointMass,
    steps: u64,
    blown: u64,
}

impl VecEnvironment for BlowsUp {
    type Error = <PointMass as VecEnvironment>::Error;
    fn num_envs(&self) -> usize {
        self.inner.num_envs()
    }
    fn obs_dim(&self) -> usize {
        self.inner.obs_dim()
    }
    fn act_dim(&self) -> usize {
        self.inner.act_dim()
    }
    fn num_tasks(&self) -> usize {
        self.inner.num_tasks()
    }
    fn task_ids(&self) -> &[usize] {
        self.inner.task_ids()
    }
    fn reset_all(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), Self::Error> {
        self.inner.reset_all(seed, obs)
    }
    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), Self::Error> {
        self.inner.step(actions, out)?;
        self.steps += 1;
        out.unstable.fill(false);
        if self.steps.is_multiple_of(7) {
            out.unstable[0] = true;
            out.truncated[0] = true;
            out.final_obs[0] = f32::NAN;
            self.blown += 1;
        }
        Ok(())
    }
}

#[test]
fn unstable_steps_are_dropped_and_counted_not_replayed() {
    let cfg = PointMassConfig::default();
    let mut env = BlowsUp {
        inner: PointMass::new(cfg.clone()),
        steps: 0,
        blown: 0,
    };
    let mut eval_env = PointMass::new(cfg.clone());
    let mut sac = Sac::new(SacConfig {
        obs_dim: 2,
        act_dim: 2,
        num_tasks: cfg.num_tasks,
        policy_hidden: vec![16],
        critic_hidden: vec![16],
        batch_size: 60,
        seed: 3,
        ..Default::default()
    })
    .unwrap();
    let report = train(
        &mut sac,
        &mut env,
        &mut eval_env,
        &TrainConfig {
            total_env_steps: 3_000,
            warmup_env_steps: 300,
            replay_capacity_per_task: 10_000,
            eval_every_env_steps: 0,
            eval_episodes_per_env: 1,
            ..Default::default()
        },
        |_, _| {},
    )
    .unwrap();
    let p = &report.final_progress;
    assert!(env.blown > 50);
    assert_eq!(p.unstable_transitions, env.blown);
    // Every batch sampled task 0's replay; one stored NaN would have been rejected.
    assert_eq!(p.rejected_batches, 0, "a blown-up step reached replay");
    assert!(p.updates > 0);
}
