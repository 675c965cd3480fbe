//! The rollout loop: act, step a vector of environments, hand every transition and finished
//! episode to a sink. `terl train` and the actors run this one loop; what differs is where
//! actions come from ([`PolicySource`]) and where data goes ([`TransitionSink`]).
//!
//! Per vector step, in order: [`PolicySource::refresh`] (newest weights, or stop), the actions
//! ([`PolicySource::act`], or uniform in `[-1, 1]` while it has no policy), one
//! [`VecEnvironment::step`], then [`TransitionSink::transition`] for each environment whose
//! step is a transition of its task (unstable physics steps are dropped and counted), then
//! [`TransitionSink::episode`] for each episode that ended, then [`TransitionSink::end_step`]
//! (updates, logs, pauses, or stop).

use crate::env::{StepBuffers, VecEnvironment};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

/// The error type sources and sinks convert their errors to.
pub type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// Whether the loop goes on after a call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Go on.
    Continue,
    /// End the loop after this call.
    Stop,
}

/// Why the rollout loop stopped early.
#[derive(Debug, Error)]
pub enum RolloutError {
    /// The environment's reset or step failed.
    #[error("environment error: {0}")]
    Env(BoxError),
    /// The [`PolicySource`] failed.
    #[error("policy source: {0}")]
    Policy(BoxError),
    /// The [`TransitionSink`] failed.
    #[error("transition sink: {0}")]
    Sink(BoxError),
}

/// One environment's transition of the last vector step. Slices are rows of length
/// `obs_dim` (observations) or `act_dim` (action).
#[derive(Clone, Copy, Debug)]
pub struct StepRecord<'a> {
    /// Index of the environment in the vector.
    pub env: usize,
    /// Task id of the environment ([`VecEnvironment::task_ids`]).
    pub task: usize,
    /// Observation the action was chosen from.
    pub obs: &'a [f32],
    /// Action executed (in `[-1, 1]`).
    pub action: &'a [f32],
    /// Reward of the step.
    pub reward: f32,
    /// Observation the action reached: at an episode's end its true last observation, not the
    /// reset observation the environment continues from.
    pub next_obs: &'a [f32],
    /// The episode reached a true terminal state (no bootstrap).
    pub terminated: bool,
    /// The episode hit its time limit (bootstrap).
    pub truncated: bool,
    /// The task's success criterion holds after this step.
    pub success: bool,
    /// The action came from the planner (TERL guidance), not from the policy.
    pub guided: bool,
    /// What guidance did at this step ([`PolicySource::guidance_step`]; default without it).
    pub guidance: crate::guidance::GuidanceStep,
    /// Version of the policy that acted ([`PolicySource::version`]; 0: random actions).
    pub policy_version: u64,
}

/// An episode that ended in the last vector step.
#[derive(Clone, Copy, Debug)]
pub struct EpisodeRecord<'a> {
    /// Index of the environment in the vector.
    pub env: usize,
    /// Task id of the environment ([`VecEnvironment::task_ids`]).
    pub task: usize,
    /// Sum of the episode's rewards.
    pub episode_return: f64,
    /// Steps of the episode, including an unstable last one.
    pub length: u32,
    /// Success at any step (Meta-World's rule).
    pub success: bool,
    /// The episode was cut short by unstable physics.
    pub unstable: bool,
    /// The episode's last observation (`obs_dim`).
    pub final_obs: &'a [f32],
    /// Policy version when the previous episode of this environment ended (0 for the first),
    /// i.e. the version the episode began with.
    pub policy_version: u64,
    /// The goal variation the episode ran on ([`VecEnvironment::variation`] at its start).
    pub variation: Option<u32>,
}

/// Counts since the loop started, passed to [`PolicySource::refresh`] and
/// [`TransitionSink::end_step`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RolloutProgress {
    /// Environment steps (vector steps × environments).
    pub env_steps: u64,
    /// Vector steps (calls of [`VecEnvironment::step`]).
    pub vec_steps: u64,
    /// Finished episodes over all environments.
    pub episodes: u64,
    /// Finished episodes with success at any step.
    pub successes: u64,
    /// Environment steps whose action came from the planner.
    pub guided_steps: u64,
    /// Steps dropped because the physics went unstable (not transitions of the task).
    pub unstable_steps: u64,
    /// [`PolicySource::version`] after the last refresh.
    pub policy_version: u64,
    /// [`PolicySource::planner_version`] after the last refresh.
    pub planner_version: Option<u64>,
}

/// Where actions come from.
pub trait PolicySource {
    /// The source's error, boxed into [`RolloutError::Policy`].
    type Error: Into<BoxError>;

    /// Before every vector step: take the newest weights (or pause). [`Flow::Stop`] ends the
    /// loop before stepping.
    fn refresh(&mut self, progress: &RolloutProgress) -> Result<Flow, Self::Error>;

    /// Version of the policy acting now (stamped on transitions; 0 before any weights).
    fn version(&self) -> u64;

    /// Version of the planner guiding actions, if any.
    fn planner_version(&self) -> Option<u64> {
        None
    }

    /// Writes actions (rows × act_dim, in `[-1, 1]`) for `obs` (rows × obs_dim) of tasks
    /// `task_ids`, drawing noise from `rng`, and marks in `guided` (all `false` on entry) the
    /// rows the planner chose. Returns `false` when there is no policy yet: the loop then acts
    /// uniformly at random.
    fn act(
        &mut self,
        obs: &[f32],
        task_ids: &[usize],
        rng: &mut ChaCha8Rng,
        actions: &mut [f32],
        guided: &mut [bool],
    ) -> Result<bool, Self::Error>;

    /// What guidance did for environment `env` at the last [`Self::act`] (σ^N, the
    /// `f_t ≥ f_{t−1}` comparison, ‖AN − π‖); the default: no guidance.
    fn guidance_step(&self, env: usize) -> crate::guidance::GuidanceStep {
        let _ = env;
        crate::guidance::GuidanceStep::default()
    }

    /// Environment `env`'s episode ended (e.g. to count episodes for guidance).
    fn end_episode(&mut self, env: usize) {
        let _ = env;
    }
}

/// Where transitions and finished episodes go.
pub trait TransitionSink {
    /// The sink's error, boxed into [`RolloutError::Sink`].
    type Error: Into<BoxError>;

    /// One transition of the last vector step (in environment order).
    fn transition(&mut self, step: &StepRecord<'_>) -> Result<(), Self::Error>;

    /// Environment `env`'s last step was dropped for unstable physics (`guided`: the planner
    /// chose its action).
    fn unstable(&mut self, env: usize, guided: bool) {
        let _ = (env, guided);
    }

    /// An episode that ended in the last vector step (after all of that step's transitions).
    fn episode(&mut self, episode: &EpisodeRecord<'_>) -> Result<(), Self::Error>;

    /// After every vector step: updates, logs, checks. `rng` is the loop's generator (the one
    /// exploration draws from). [`Flow::Stop`] ends the loop.
    fn end_step(
        &mut self,
        progress: &RolloutProgress,
        rng: &mut ChaCha8Rng,
    ) -> Result<Flow, Self::Error>;
}

/// Resets `env` with `seed`, then steps it until `policy` or `sink` says stop. Exploration
/// draws (random actions, policy noise, guidance) come from one `ChaCha8Rng` seeded with
/// `seed`, which `sink.end_step` shares. Returns the final counts.
///
/// Errors: the environment's, the source's or the sink's first error, which ends the loop.
pub fn run<E, P, S>(
    env: &mut E,
    policy: &mut P,
    sink: &mut S,
    seed: u64,
) -> Result<RolloutProgress, RolloutError>
where
    E: VecEnvironment,
    P: PolicySource,
    S: TransitionSink,
{
    let (n, od, ad) = (env.num_envs(), env.obs_dim(), env.act_dim());
    let task_ids = env.task_ids().to_vec();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut obs = vec![0.0f32; n * od];
    let mut actions = vec![0.0f32; n * ad];
    let mut guided = vec![false; n];
    let mut out = StepBuffers::new(n, od);
    let (mut ep_return, mut ep_length) = (vec![0.0f64; n], vec![0u32; n]);
    let (mut ep_success, mut ep_unstable) = (vec![false; n], vec![false; n]);
    let mut ep_version = vec![0u64; n];
    let mut progress = RolloutProgress::default();
    let env_error = |e: E::Error| RolloutError::Env(Box::new(e));
    let policy_error = |e: P::Error| RolloutError::Policy(e.into());
    let sink_error = |e: S::Error| RolloutError::Sink(e.into());
    env.reset_all(seed, &mut obs).map_err(env_error)?;
    let mut ep_variation: Vec<Option<u32>> = (0..n).map(|i| env.variation(i)).collect();
    loop {
        let flow = policy.refresh(&progress).map_err(policy_error)?;
        let version = policy.version();
        progress.policy_version = version;
        progress.planner_version = policy.planner_version();
        if flow == Flow::Stop {
            break;
        }
        guided.fill(false);
        let acted = policy
            .act(&obs, &task_ids, &mut rng, &mut actions, &mut guided)
            .map_err(policy_error)?;
        if !acted {
            guided.fill(false);
            actions
                .iter_mut()
                .for_each(|a| *a = rng.gen_range(-1.0..1.0));
        }
        env.step(&actions, &mut out).map_err(env_error)?;
        for i in 0..n {
            progress.guided_steps += u64::from(guided[i]);
            ep_return[i] += f64::from(out.reward[i]);
            ep_length[i] += 1;
            ep_success[i] |= out.success[i];
            ep_unstable[i] |= out.unstable[i];
            if out.unstable[i] {
                progress.unstable_steps += 1;
                sink.unstable(i, guided[i]);
                continue;
            }
            sink.transition(&StepRecord {
                env: i,
                task: task_ids[i],
                obs: &obs[i * od..(i + 1) * od],
                action: &actions[i * ad..(i + 1) * ad],
                reward: out.reward[i],
                next_obs: &out.final_obs[i * od..(i + 1) * od],
                terminated: out.terminated[i],
                truncated: out.truncated[i],
                success: out.success[i],
                guided: guided[i],
                guidance: if acted {
                    policy.guidance_step(i)
                } else {
                    crate::guidance::GuidanceStep::default()
                },
                policy_version: version,
            })
            .map_err(sink_error)?;
        }
        for i in 0..n {
            if !(out.terminated[i] || out.truncated[i]) {
                continue;
            }
            policy.end_episode(i);
            sink.episode(&EpisodeRecord {
                env: i,
                task: task_ids[i],
                episode_return: ep_return[i],
                length: ep_length[i],
                success: ep_success[i],
                unstable: ep_unstable[i],
                final_obs: &out.final_obs[i * od..(i + 1) * od],
                policy_version: ep_version[i],
                variation: ep_variation[i],
            })
            .map_err(sink_error)?;
            // The environment reset itself in `step`: the next episode's variation.
            ep_variation[i] = env.variation(i);
            progress.episodes += 1;
            progress.successes += u64::from(ep_success[i]);
            (ep_return[i], ep_length[i]) = (0.0, 0);
            (ep_success[i], ep_unstable[i]) = (false, false);
            ep_version[i] = version;
        }
        obs.copy_from_slice(&out.obs);
        progress.env_steps += n as u64;
        progress.vec_steps += 1;
        if sink.end_step(&progress, &mut rng).map_err(sink_error)? == Flow::Stop {
            break;
        }
    }
    Ok(progress)
}
