//! The rollout loop (`terl_rl::rollout`) on real Meta-World environments, with an in-memory
//! sink and a fixed policy: episode boundaries at the time limit, one transition per stable
//! step, observation continuity across steps, policy versions stamped, random actions before
//! the first weights, unstable physics steps dropped and counted.

use rand_chacha::ChaCha8Rng;
use terl_rl::env::{StepBuffers, VecEnvironment};
use terl_rl::rollout::{
    self, EpisodeRecord, Flow, PolicySource, RolloutProgress, StepRecord, TransitionSink,
};
use terl_runtime::MetaWorldVec;
use terl_sim::metaworld::{Env, MAX_PATH_LENGTH};
use terl_sim::OBS_DIM;

const TASKS: [&str; 2] = ["reach-v3", "push-v3"];
const SEED: u64 = 11;

/// A scripted action of vector step `step` (the same for every environment).
fn action(step: u64) -> [f32; 4] {
    let t = step as f32 * 0.05;
    [t.sin(), t.cos(), (0.5 * t).sin(), 0.3]
}

/// Acts with [`action`] from vector step `first_weights_at` on, at version `1 + step / 100`;
/// before that it has no weights (version 0).
#[derive(Debug)]
struct FixedPolicy {
    first_weights_at: u64,
    step: u64,
    version: u64,
    ended: Vec<usize>,
}

impl PolicySource for FixedPolicy {
    type Error = std::io::Error;

    fn refresh(&mut self, progress: &RolloutProgress) -> Result<Flow, Self::Error> {
        self.step = progress.vec_steps;
        self.version = if self.step >= self.first_weights_at {
            1 + self.step / 100
        } else {
            0
        };
        Ok(Flow::Continue)
    }
    fn version(&self) -> u64 {
        self.version
    }
    fn act(
        &mut self,
        _obs: &[f32],
        task_ids: &[usize],
        _rng: &mut ChaCha8Rng,
        actions: &mut [f32],
        _guided: &mut [bool],
    ) -> Result<bool, Self::Error> {
        if self.version == 0 {
            return Ok(false);
        }
        for row in actions.chunks_mut(4).take(task_ids.len()) {
            row.copy_from_slice(&action(self.step));
        }
        Ok(true)
    }
    fn end_episode(&mut self, env: usize) {
        self.ended.push(env);
    }
}

#[derive(Debug, Clone)]
struct Step {
    vec_step: u64,
    env: usize,
    task: usize,
    obs: Vec<f32>,
    action: Vec<f32>,
    reward: f32,
    next_obs: Vec<f32>,
    truncated: bool,
    success: bool,
    version: u64,
}

#[derive(Debug, Clone)]
struct Episode {
    vec_step: u64,
    env: usize,
    episode_return: f64,
    length: u32,
    success: bool,
    unstable: bool,
    final_obs: Vec<f32>,
    version: u64,
    variation: Option<u32>,
}

/// Keeps everything in memory; stops after `vec_steps` vector steps.
#[derive(Debug, Default)]
struct MemorySink {
    vec_steps: u64,
    now: u64,
    steps: Vec<Step>,
    episodes: Vec<Episode>,
    unstable: Vec<(u64, usize)>,
}

impl TransitionSink for MemorySink {
    type Error = std::io::Error;

    fn transition(&mut self, s: &StepRecord<'_>) -> Result<(), Self::Error> {
        self.steps.push(Step {
            vec_step: self.now,
            env: s.env,
            task: s.task,
            obs: s.obs.to_vec(),
            action: s.action.to_vec(),
            reward: s.reward,
            next_obs: s.next_obs.to_vec(),
            truncated: s.truncated,
            success: s.success,
            version: s.policy_version,
        });
        Ok(())
    }
    fn unstable(&mut self, env: usize, _guided: bool) {
        self.unstable.push((self.now, env));
    }
    fn episode(&mut self, e: &EpisodeRecord<'_>) -> Result<(), Self::Error> {
        self.episodes.push(Episode {
            vec_step: self.now,
            env: e.env,
            episode_return: e.episode_return,
            length: e.length,
            success: e.success,
            unstable: e.unstable,
            final_obs: e.final_obs.to_vec(),
            version: e.policy_version,
            variation: e.variation,
        });
        Ok(())
    }
    fn end_step(
        &mut self,
        progress: &RolloutProgress,
        _rng: &mut ChaCha8Rng,
    ) -> Result<Flow, Self::Error> {
        self.now = progress.vec_steps;
        Ok(if progress.vec_steps >= self.vec_steps {
            Flow::Stop
        } else {
            Flow::Continue
        })
    }
}

fn env() -> MetaWorldVec {
    MetaWorldVec::with_envs(&TASKS, &TASKS, 3).unwrap()
}

#[test]
fn rollout_on_meta_world_ends_episodes_at_the_time_limit_and_stamps_versions() {
    let mut env = env();
    let mut policy = FixedPolicy {
        first_weights_at: 10,
        step: 0,
        version: 0,
        ended: Vec::new(),
    };
    let vec_steps = 2 * u64::from(MAX_PATH_LENGTH) + 7;
    let mut sink = MemorySink {
        vec_steps,
        ..Default::default()
    };
    let progress = rollout::run(&mut env, &mut policy, &mut sink, SEED).unwrap();
    assert_eq!(progress.vec_steps, vec_steps);
    assert_eq!(progress.env_steps, 2 * vec_steps);
    assert_eq!(progress.unstable_steps, 0);
    // One transition per environment and step, in environment order within a step.
    assert_eq!(sink.steps.len() as u64, 2 * vec_steps);
    for (k, s) in sink.steps.iter().enumerate() {
        assert_eq!((s.vec_step, s.env), (k as u64 / 2, k % 2));
        assert_eq!(s.task, s.env, "task ids are positions in the task list");
        // Versions as the source gave them; random actions in [-1, 1] before the first weights.
        let want = if s.vec_step >= 10 {
            1 + s.vec_step / 100
        } else {
            0
        };
        assert_eq!(s.version, want, "vec step {}", s.vec_step);
        if want == 0 {
            assert!(s.action.iter().all(|a| (-1.0..1.0).contains(a)));
            assert_ne!(s.action[..], action(s.vec_step)[..]);
        } else {
            assert_eq!(s.action[..], action(s.vec_step)[..]);
        }
        // Episodes end exactly at the time limit.
        assert_eq!(
            s.truncated,
            (s.vec_step + 1) % u64::from(MAX_PATH_LENGTH) == 0,
            "vec step {}",
            s.vec_step
        );
    }
    // Continuity: each step starts where the previous one ended, except after a reset.
    for env_index in 0..2 {
        let mine: Vec<&Step> = sink.steps.iter().filter(|s| s.env == env_index).collect();
        for w in mine.windows(2) {
            if w[0].truncated {
                assert_ne!(w[1].obs, w[0].next_obs, "a reset starts a new episode");
            } else {
                assert_eq!(w[1].obs, w[0].next_obs, "vec step {}", w[1].vec_step);
            }
        }
    }
    // Two episodes per environment, each summing its own transitions.
    assert_eq!(sink.episodes.len(), 4);
    assert_eq!(progress.episodes, 4);
    assert_eq!(policy.ended, [0, 1, 0, 1]);
    for (k, e) in sink.episodes.iter().enumerate() {
        let round = k as u64 / 2;
        assert_eq!(e.env, k % 2);
        assert_eq!(e.vec_step, (round + 1) * u64::from(MAX_PATH_LENGTH) - 1);
        assert_eq!(e.length, MAX_PATH_LENGTH);
        assert!(!e.unstable);
        let own: Vec<&Step> = sink
            .steps
            .iter()
            .filter(|s| s.env == e.env && s.vec_step / u64::from(MAX_PATH_LENGTH) == round)
            .collect();
        assert_eq!(own.len() as u32, MAX_PATH_LENGTH);
        let sum: f64 = own.iter().map(|s| f64::from(s.reward)).sum();
        assert!((e.episode_return - sum).abs() < 1e-6 * sum.abs().max(1.0));
        assert_eq!(e.success, own.iter().any(|s| s.success));
        assert_eq!(e.final_obs, own.last().unwrap().next_obs);
        // The goal variation the episode ran on: a fresh environment reset to that variation
        // (of the vector's variation seed, 3) starts where the episode started.
        let v = e.variation.expect("Meta-World records the variation") as usize;
        let start = Env::new(TASKS[e.env])
            .unwrap()
            .reset_variation(3, v)
            .unwrap()
            .map(|x| x as f32);
        assert_eq!(own[0].obs[..], start[..], "episode {k}, variation {v}");
        // The version the episode began with: the one that acted when the previous ended.
        let want = if round == 0 {
            0
        } else {
            1 + (u64::from(MAX_PATH_LENGTH) - 1) / 100
        };
        assert_eq!(e.version, want);
    }
}

#[test]
fn the_time_limit_transition_carries_the_true_last_observation() {
    // The first episode of environment 0 replayed on a plain `Env` from the same variation.
    let mut replica = env();
    let mut first = vec![0.0; 2 * OBS_DIM];
    replica.reset_all(SEED, &mut first).unwrap();
    let mut single = Env::new(TASKS[0]).unwrap();
    let start = single.reset(replica.inner().env(0).rand_vec()).unwrap();

    let mut env = env();
    let mut policy = FixedPolicy {
        first_weights_at: 0,
        step: 0,
        version: 0,
        ended: Vec::new(),
    };
    let mut sink = MemorySink {
        vec_steps: u64::from(MAX_PATH_LENGTH) + 1,
        ..Default::default()
    };
    rollout::run(&mut env, &mut policy, &mut sink, SEED).unwrap();
    let mine: Vec<&Step> = sink.steps.iter().filter(|s| s.env == 0).collect();
    for (k, (&got, &want)) in mine[0].obs.iter().zip(&start).enumerate() {
        assert!((f64::from(got) - want).abs() < 1e-5, "first obs[{k}]");
    }
    for s in &mine[..MAX_PATH_LENGTH as usize] {
        let expected = single.step(&s.action).unwrap();
        assert_eq!(s.truncated, expected.truncated);
        for (k, (&got, &want)) in s.next_obs.iter().zip(&expected.obs).enumerate() {
            assert!(
                (f64::from(got) - want).abs() < 1e-5,
                "vec step {} next_obs[{k}]: transition {got}, replayed env {want}",
                s.vec_step
            );
        }
    }
    // After the time limit the environment continues from a reset observation, which the
    // last transition does not carry.
    let last = mine[MAX_PATH_LENGTH as usize - 1];
    assert!(last.truncated);
    assert_ne!(mine[MAX_PATH_LENGTH as usize].obs, last.next_obs);
}

/// Breaks environment 1's physics before vector step `at`.
#[derive(Debug)]
struct BlowUp {
    inner: MetaWorldVec,
    at: u64,
    steps: u64,
}

impl VecEnvironment for BlowUp {
    type Error = terl_sim::SimError;
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
        if self.steps == self.at {
            self.inner.inner_mut().env_mut(1).inject_nan_velocity();
        }
        self.steps += 1;
        self.inner.step(actions, out)
    }
}

#[test]
fn an_unstable_step_is_dropped_counted_and_ends_its_episode() {
    let mut env = BlowUp {
        inner: env(),
        at: 3,
        steps: 0,
    };
    let mut policy = FixedPolicy {
        first_weights_at: 0,
        step: 0,
        version: 0,
        ended: Vec::new(),
    };
    let mut sink = MemorySink {
        vec_steps: 6,
        ..Default::default()
    };
    let progress = rollout::run(&mut env, &mut policy, &mut sink, SEED).unwrap();
    assert_eq!(progress.unstable_steps, 1);
    assert_eq!(sink.unstable, [(3, 1)]);
    assert_eq!(sink.steps.len(), 2 * 6 - 1);
    assert!(!sink.steps.iter().any(|s| s.env == 1 && s.vec_step == 3));
    assert_eq!(sink.episodes.len(), 1);
    let e = &sink.episodes[0];
    assert_eq!((e.env, e.vec_step, e.length, e.unstable), (1, 3, 4, true));
    // The environment was reset and steps normally again.
    assert!(sink.steps.iter().any(|s| s.env == 1 && s.vec_step == 4));
}
