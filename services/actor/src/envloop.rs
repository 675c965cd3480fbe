//! The actor's environment loop (its own thread): the rollout loop of `terl_rl::rollout` with
//! the actor's policy source (newest weights between steps, TERL guidance) and transition sink
//! (batches of transitions, finished episodes, the pause while the learner is away).

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Context;
use rand_chacha::ChaCha8Rng;
use terl_rl::guidance::{BatchGuidance, GoalTarget, GuidanceStep};
use terl_rl::rollout::{
    self, EpisodeRecord, Flow, PolicySource, RolloutProgress, StepRecord, TransitionSink,
};
use terl_rl::{Policy, PolicySpec};
use terl_runtime::{Algorithm, Lockstep, MetaWorldVec, RunConfig};
use terl_transport::{
    flags, EpisodeSummary, HeldClaim, Message, MessageSink, ServiceTransport, TrajectoryStep,
    Transition, TransitionBatch, TransportError, ACTION_DIM, OBS_DIM,
};

use crate::{ActorConfig, Mailbox};

/// How long an actor waits at start-up for the learner and selector to subscribe before it
/// starts anyway (messages sent before then reach nobody and are counted as `no_receiver`).
const STARTUP_WAIT: Duration = Duration::from_secs(60);
const LOG_EVERY: Duration = Duration::from_secs(10);
/// How long a failed send waits for this actor's own shutdown signal before it is an error.
const PEER_GONE_GRACE: Duration = Duration::from_secs(2);
/// While the learner is away the actor checks for it after 0.25 s, then doubles the wait up to
/// 5 s (the same schedule as the weight follower's reconnects).
const AWAY_BACKOFF_MIN: Duration = Duration::from_millis(250);
const AWAY_BACKOFF_MAX: Duration = Duration::from_secs(5);
/// Once the learner is back, how long the actor waits for its first weights before it goes on
/// with the ones it has.
const REJOIN_WEIGHTS_WAIT: Duration = Duration::from_secs(30);
/// How often a running actor removes dead processes' subscriptions (iceoryx2's dead-node
/// cleanup) to notice a killed learner.
const LEARNER_CHECK_EVERY: Duration = Duration::from_secs(1);

/// How a pause for an absent learner ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Rejoin {
    /// The learner subscribes again and sent weights (or [`REJOIN_WEIGHTS_WAIT`] passed).
    Back { waited: Duration, checks: u32 },
    /// This actor was asked to stop while waiting.
    Stopped,
}

/// Pauses the environment loop while no learner receives transitions (it crashed, was killed
/// or is restarting), instead of stepping environments whose transitions would reach nobody.
/// Checks for the learner with back-off ([`AWAY_BACKOFF_MIN`] doubling to
/// [`AWAY_BACKOFF_MAX`]), calling `cleanup` first each time (the shared-memory transport's
/// dead-node cleanup, which removes the subscription a killed learner leaves behind). When a
/// receiver is back and this actor had received weights before, waits until the mailbox holds
/// a policy posted after the pause began (the weight follower reconnects on its own), at most
/// [`REJOIN_WEIGHTS_WAIT`]. Never busy-waits:
/// it sleeps in slices of at most 50 ms to notice `mailbox.stop`.
pub(crate) fn wait_for_learner(
    transitions: &dyn MessageSink<TransitionBatch>,
    mut cleanup: impl FnMut(),
    mailbox: &Mailbox,
) -> Rejoin {
    let began = Instant::now();
    let posts_before = mailbox.policy_posts.load(Ordering::Relaxed);
    let nap = |d: Duration| -> bool {
        let until = Instant::now() + d;
        while Instant::now() < until {
            if mailbox.stop.load(Ordering::Relaxed) {
                return false;
            }
            std::thread::sleep((until - Instant::now()).min(Duration::from_millis(50)));
        }
        !mailbox.stop.load(Ordering::Relaxed)
    };
    let mut backoff = AWAY_BACKOFF_MIN;
    let mut checks = 0u32;
    loop {
        cleanup();
        checks += 1;
        if transitions.receivers() > 0 {
            break;
        }
        if !nap(backoff) {
            return Rejoin::Stopped;
        }
        backoff = (backoff * 2).min(AWAY_BACKOFF_MAX);
    }
    // A learner that resumes publishes its restored policy at once; a fresh one publishes only
    // after its warm-up, which needs this actor's transitions, so only an actor that had
    // weights waits for new ones.
    let deadline = Instant::now() + REJOIN_WEIGHTS_WAIT;
    while posts_before > 0 && mailbox.policy_posts.load(Ordering::Relaxed) == posts_before {
        if Instant::now() >= deadline {
            tracing::warn!(
                "the learner is back but sent no weights within {REJOIN_WEIGHTS_WAIT:?}; going on \
                 with the policy this actor has"
            );
            break;
        }
        if !nap(Duration::from_millis(50)) {
            return Rejoin::Stopped;
        }
    }
    Rejoin::Back {
        waited: began.elapsed(),
        checks,
    }
}

/// Sends `message`; returns whether the loop should go on. A send that timed out on a full
/// receiver (a receiver stopped or stalled for longer than the block timeout) is not fatal:
/// the transport drops the message, counts it (`dropped`/`dropped_items` of the sink's stats)
/// and stamps the cumulative counts on every later message, so the learner and the selector
/// learn about it from the next message that gets through; here it is logged. Any other failure is fatal unless this actor's own shutdown follows
/// within a moment: on Ctrl-C the learner and selector get the signal too and may close their
/// side first, which is a clean stop, not an error.
fn send<M: Message>(
    sink: &mut dyn MessageSink<M>,
    message: &M,
    mailbox: &Mailbox,
) -> anyhow::Result<bool> {
    match sink.send(message) {
        Ok(_) => Ok(true),
        Err(e @ TransportError::BlockTimeout { .. }) => {
            let lost = sink.stats();
            tracing::warn!(
                dropped = lost.dropped,
                dropped_items = lost.dropped_items,
                "{e}; dropped and counted (totals of this stream so far)"
            );
            Ok(true)
        }
        Err(e) => {
            let deadline = Instant::now() + PEER_GONE_GRACE;
            while Instant::now() < deadline {
                if mailbox.stop.load(Ordering::Relaxed) {
                    tracing::info!("a receiver closed during shutdown ({e}); stopping");
                    return Ok(false);
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e.into())
        }
    }
}

fn row<const N: usize>(flat: &[f32], i: usize) -> [f32; N] {
    flat[i * N..(i + 1) * N]
        .try_into()
        .expect("row of the right width")
}

/// The message of one transition of the rollout loop: the observations, action and reward,
/// the version of the policy that acted, the `TRUNCATED`, `SUCCESS` and `GUIDED` flags, and what
/// guidance did (`GUIDANCE_ACTIVE` with σ^N, `COMPARED`/`NOT_IMPROVING`, ‖AN − π‖).
/// `next_obs` is the observation the action reached (at the time limit the episode's true last
/// observation, not the reset observation the environment continues from); unstable physics
/// steps never get here (the rollout loop drops and counts them).
pub(crate) fn transition_of(step: &StepRecord<'_>, actor_id: u16, task: u16) -> Transition {
    let mut f = 0;
    if step.truncated {
        f |= flags::TRUNCATED;
    }
    if step.success {
        f |= flags::SUCCESS;
    }
    if step.guided {
        f |= flags::GUIDED;
    }
    let g = &step.guidance;
    if g.active {
        f |= flags::GUIDANCE_ACTIVE;
    }
    if let Some(not_improving) = g.not_improving {
        f |= flags::COMPARED;
        if not_improving {
            f |= flags::NOT_IMPROVING;
        }
    }
    let mut t = Transition {
        policy_version: step.policy_version,
        obs: row(step.obs, 0),
        next_obs: row(step.next_obs, 0),
        action: row(step.action, 0),
        reward: step.reward,
        actor_id,
        env_index: step.env as u16,
        task,
        flags: f,
        ..Transition::ZERO
    };
    if g.active {
        t.set_guidance_probability(g.probability);
    }
    if let Some(gap) = g.action_gap {
        t.set_action_gap(gap);
    }
    t
}

/// The actor's policy source: the newest policy from the mailbox (uniform random actions until
/// the first version arrives) and, with `algorithm = "terl"`, TERL guidance (Eq. 15) with the
/// newest planner weights.
struct ActorPolicy<'a> {
    policy: Policy,
    guide: Option<BatchGuidance>,
    mailbox: &'a Mailbox,
    /// `[cluster] reproducible = true`: the schedule that fixes the version of each batch.
    lockstep: Option<Lockstep>,
}

/// How a reproducible actor's wait for the version its batch needs ended.
#[derive(Debug, PartialEq, Eq)]
enum Scheduled {
    /// The version is loaded (or none is due yet: random actions).
    Ready,
    /// This actor was asked to stop while waiting.
    Stopped,
}

impl ActorPolicy<'_> {
    /// Loads exactly the policy version the schedule fixes for the batch being filled, waiting
    /// for it to arrive; older versions still in the mailbox are passed over.
    ///
    /// # Errors
    /// The mailbox holds a newer version than the one due (the learner runs another schedule),
    /// or weights that do not fit the policy.
    fn load_scheduled(&mut self, schedule: &Lockstep) -> anyhow::Result<Scheduled> {
        let batch = self.mailbox.sent_batches.load(Ordering::Relaxed);
        let due = schedule.policy_version_for_batch(batch);
        let began = Instant::now();
        let mut log_at = SCHEDULED_LOG_AFTER;
        while self.policy.version != due {
            if self.mailbox.stop.load(Ordering::Relaxed) {
                return Ok(Scheduled::Stopped);
            }
            let fresh = self.mailbox.slot.lock().ok().and_then(|mut s| s.take());
            match fresh {
                Some((version, params)) if version == due => {
                    self.policy
                        .set_params(&params, version)
                        .with_context(|| format!("policy version {version}"))?;
                }
                Some((version, _)) if version > due => anyhow::bail!(
                    "reproducible run: the learner published policy version {version} while                      batch {batch} of this actor needs version {due} (do the learner and this                      actor read the same run file and actor count?)"
                ),
                // An older version, delivered late: the due one follows.
                Some(_) => {}
                None => {
                    std::thread::sleep(SCHEDULED_POLL);
                    if began.elapsed() >= log_at {
                        tracing::info!(
                            batch,
                            due,
                            waited_secs = began.elapsed().as_secs(),
                            "reproducible run: waiting for the policy version this batch needs"
                        );
                        log_at += SCHEDULED_LOG_AFTER;
                    }
                }
            }
        }
        Ok(Scheduled::Ready)
    }
}

/// How often a reproducible actor looks for the version it waits for.
const SCHEDULED_POLL: Duration = Duration::from_micros(200);
/// A reproducible actor waiting this long (and every as long again) logs what it waits for.
const SCHEDULED_LOG_AFTER: Duration = Duration::from_secs(30);

impl PolicySource for ActorPolicy<'_> {
    type Error = anyhow::Error;

    fn refresh(&mut self, _: &RolloutProgress) -> Result<Flow, Self::Error> {
        if self.mailbox.stop.load(Ordering::Relaxed) {
            return Ok(Flow::Stop);
        }
        if let Some(schedule) = self.lockstep {
            return Ok(match self.load_scheduled(&schedule)? {
                Scheduled::Ready => Flow::Continue,
                Scheduled::Stopped => Flow::Stop,
            });
        }
        let fresh = self.mailbox.slot.lock().ok().and_then(|mut s| s.take());
        if let Some((version, params)) = fresh {
            match self.policy.set_params(&params, version) {
                Ok(()) => tracing::debug!(version, "loaded policy weights"),
                Err(e) => tracing::warn!(version, "ignoring policy weights: {e}"),
            }
        }
        if let Some(g) = self.guide.as_mut() {
            let fresh = self.mailbox.planner.lock().ok().and_then(|mut s| s.take());
            if let Some(p) = fresh {
                let version = p.version;
                match g.planner_mut().set_params(&p.f, &p.an, version) {
                    Ok(()) => {
                        tracing::debug!(version, "loaded planner weights");
                        if let Some(gate) = &p.gate {
                            g.set_validated(gate);
                        }
                        if let Some(lib) = p.goals {
                            g.set_library(lib);
                        }
                    }
                    Err(e) => tracing::warn!(version, "ignoring planner weights: {e}"),
                }
            }
        }
        Ok(Flow::Continue)
    }

    fn version(&self) -> u64 {
        self.policy.version
    }

    fn planner_version(&self) -> Option<u64> {
        self.guide.as_ref().map(|g| g.planner().version())
    }

    fn act(
        &mut self,
        obs: &[f32],
        task_ids: &[usize],
        rng: &mut ChaCha8Rng,
        actions: &mut [f32],
        guided: &mut [bool],
    ) -> Result<bool, Self::Error> {
        if self.policy.version == 0 {
            return Ok(false);
        }
        self.policy.act(obs, task_ids, false, rng, actions)?;
        if let Some(g) = self.guide.as_mut() {
            g.apply(obs, actions, rng);
            guided.copy_from_slice(g.guided());
        }
        Ok(true)
    }

    fn guidance_step(&self, env: usize) -> GuidanceStep {
        self.guide
            .as_ref()
            .map_or_else(GuidanceStep::default, |g| g.step(env))
    }

    fn end_episode(&mut self, env: usize) {
        if let Some(g) = self.guide.as_mut() {
            g.end_episode(env);
        }
    }
}

/// The actor's transition sink: transitions in [`TransitionBatch`]es to the learner, finished
/// episodes with their trajectories ([`EpisodeSummary`]) to the learner and the selector; the
/// pause while no learner receives, and the progress log.
struct ActorSink<'a, T: ServiceTransport> {
    transport: &'a T,
    /// The actor id this process holds; a later holder of an id held twice stops.
    claim: &'a T::Claim,
    mailbox: &'a Mailbox,
    transitions: Box<dyn MessageSink<TransitionBatch>>,
    episodes: Box<dyn MessageSink<EpisodeSummary>>,
    actor_id: u16,
    /// Transitions not yet sent (sent when full).
    batch: TransitionBatch,
    sequence: u64,
    trajectories: Vec<Box<EpisodeSummary>>,
    episode_index: u64,
    /// A receiver closed during shutdown: nothing more is sent and the loop stops.
    closed: bool,
    pauses: u64,
    paused: Duration,
    log_at: Instant,
    log_steps: u64,
    dropped_seen: u64,
    checked_at: Instant,
}

impl<T: ServiceTransport> ActorSink<'_, T> {
    /// A learner killed with SIGKILL leaves its subscription behind, and sends would fill its
    /// queue and then block for `block_timeout_secs`: every second, and after any send that
    /// timed out, remove dead processes' subscriptions, so that a dead learner shows as no
    /// receiver. While no learner receives transitions, pause ([`wait_for_learner`]).
    fn check_learner(&mut self) -> Flow {
        let dropped = self.transitions.stats().dropped;
        if dropped > self.dropped_seen || self.checked_at.elapsed() >= LEARNER_CHECK_EVERY {
            self.dropped_seen = dropped;
            self.checked_at = Instant::now();
            self.transport.cleanup_dead_nodes();
        }
        if self.transitions.receivers() > 0 {
            return Flow::Continue;
        }
        tracing::warn!(
            actor_id = self.actor_id,
            "no learner receives transitions (stopped, killed or restarting): pausing the \
             environments and checking for it with back-off"
        );
        let transport = self.transport;
        match wait_for_learner(
            &*self.transitions,
            || {
                transport.cleanup_dead_nodes();
            },
            self.mailbox,
        ) {
            Rejoin::Stopped => Flow::Stop,
            Rejoin::Back { waited, checks } => {
                self.pauses += 1;
                self.paused += waited;
                tracing::info!(
                    actor_id = self.actor_id,
                    waited_secs = format!("{:.1}", waited.as_secs_f64()),
                    checks,
                    newest_received = self.mailbox.received.load(Ordering::Relaxed),
                    "the learner is back; rejoining with its weights"
                );
                Flow::Continue
            }
        }
    }
}

impl<T: ServiceTransport> TransitionSink for ActorSink<'_, T> {
    type Error = anyhow::Error;

    fn transition(&mut self, step: &StepRecord<'_>) -> anyhow::Result<()> {
        let trajectory = &mut self.trajectories[step.env];
        if step.guided {
            trajectory.guided_steps = trajectory.guided_steps.saturating_add(1);
        }
        if self.closed {
            return Ok(());
        }
        let transition = transition_of(step, self.actor_id, task_u16(step.task));
        if step.success {
            trajectory.mark_success_at_next_step();
        }
        let _ = trajectory.push_step(TrajectoryStep {
            obs: transition.obs,
            action: transition.action,
            reward: transition.reward,
        });
        if !self.batch.push(transition) {
            unreachable!("the batch is sent as soon as it is full");
        }
        if self.batch.is_full() {
            self.batch.sequence = self.sequence;
            if !send(self.transitions.as_mut(), &self.batch, self.mailbox)? {
                self.closed = true;
                return Ok(());
            }
            self.sequence += 1;
            self.mailbox
                .sent_batches
                .store(self.sequence, Ordering::Relaxed);
            self.batch.clear();
        }
        Ok(())
    }

    fn unstable(&mut self, env: usize, guided: bool) {
        if guided {
            let t = &mut self.trajectories[env];
            t.guided_steps = t.guided_steps.saturating_add(1);
        }
    }

    fn episode(&mut self, end: &EpisodeRecord<'_>) -> anyhow::Result<()> {
        if self.closed {
            return Ok(());
        }
        let episode = &mut self.trajectories[end.env];
        episode.policy_version = end.policy_version;
        episode.episode_index = self.episode_index;
        episode.episode_return = end.episode_return as f32;
        episode.length = end.length;
        episode.actor_id = self.actor_id;
        episode.env_index = end.env as u16;
        episode.task = task_u16(end.task);
        episode.success = u8::from(end.success);
        episode.variation = end.variation.unwrap_or(terl_transport::NO_VARIATION);
        episode.final_obs = row(end.final_obs, 0);
        if !send(self.episodes.as_mut(), &**episode, self.mailbox)? {
            self.closed = true;
            return Ok(());
        }
        **episode = EpisodeSummary::EMPTY;
        self.episode_index += 1;
        Ok(())
    }

    fn end_step(&mut self, progress: &RolloutProgress, _: &mut ChaCha8Rng) -> anyhow::Result<Flow> {
        if self.closed || self.mailbox.stop.load(Ordering::Relaxed) {
            return Ok(Flow::Stop);
        }
        if self.log_at.elapsed() >= LOG_EVERY {
            let rate =
                (progress.env_steps - self.log_steps) as f64 / self.log_at.elapsed().as_secs_f64();
            tracing::info!(
                actor_id = self.actor_id,
                env_steps = progress.env_steps,
                env_steps_per_second = format!("{rate:.0}"),
                policy_version = progress.policy_version,
                newest_received = self.mailbox.received.load(Ordering::Relaxed),
                episodes = progress.episodes,
                successes = progress.successes,
                guided_steps = progress.guided_steps,
                unstable_steps_dropped = progress.unstable_steps,
                planner_version = progress.planner_version.unwrap_or(0),
                transitions = ?self.transitions.stats(),
                episode_sends = ?self.episodes.stats(),
                "progress"
            );
            (self.log_at, self.log_steps) = (Instant::now(), progress.env_steps);
        }
        if let Some(why) = self.claim.superseded() {
            anyhow::bail!(
                "actor id {} is held by two processes and this one stops: {why}",
                self.actor_id
            );
        }
        Ok(self.check_learner())
    }
}

/// A run-wide task index as the messages carry it.
fn task_u16(task: usize) -> u16 {
    u16::try_from(task).expect("at most 65535 tasks")
}

/// The environment loop of one actor. `claimed` receives the actor id once it is held (the
/// configured one, or with [`ActorConfig::auto_id`] the lowest free one).
/// Holds the actor id: the configured one, or with `auto_id` the lowest id below
/// `num_actors` that no live process holds.
fn claim<T: ServiceTransport>(
    transport: &T,
    config: &ActorConfig,
) -> anyhow::Result<(u16, T::Claim)> {
    if !config.auto_id {
        let id = u16::try_from(config.actor_id).context("actor id above 65535")?;
        return Ok((id, transport.claim_actor_id(id)?));
    }
    let max = u16::try_from(config.num_actors).context("more than 65535 actors")?;
    for id in 0..max {
        match transport.claim_actor_id(id) {
            Ok(claim) => {
                tracing::info!(actor_id = id, "took the lowest free actor id");
                return Ok((id, claim));
            }
            Err(terl_transport::TransportError::IdInUse { .. }) => continue,
            Err(e) => return Err(e.into()),
        }
    }
    anyhow::bail!(
        "all {max} actor ids of run {} are held by live actors; start the learner and selector \
         with a larger --num-actors to run more",
        config.run_id
    )
}

pub(crate) fn run<T: ServiceTransport>(
    config: &ActorConfig,
    transport: &T,
    mailbox: &Mailbox,
    claimed: tokio::sync::oneshot::Sender<usize>,
) -> anyhow::Result<()> {
    let run = &config.run;
    let tasks = terl_runtime::resolve_tasks(&run.tasks)?;
    // One actor per actor id and run, held until this function returns.
    let (actor_id, held) = claim(transport, config)?;
    tracing::Span::current().record("id", actor_id);
    let _ = claimed.send(usize::from(actor_id));
    // An actor with a fixed id steps its share of the cluster's environments; one that took
    // any free id (a replica of a scaled Deployment) steps every task, so task shares stay
    // equal for any number of replicas.
    let mine = if config.auto_id {
        RunConfig::actor_env_tasks(tasks.len(), 0, 1, run.envs_per_actor())
    } else {
        RunConfig::actor_env_tasks(
            tasks.len(),
            config.actor_id,
            config.num_actors,
            run.envs_per_actor(),
        )
    };
    let my_names: Vec<&str> = mine.iter().map(|&t| tasks[t]).collect();
    let num_envs = my_names.len();
    // Task ids of the rollout are positions in the run's task list.
    let mut env = MetaWorldVec::with_envs(&tasks, &my_names, run.variation_seed)?;
    let seed = run
        .train
        .seed
        .wrapping_add(7919 * (u64::from(actor_id) + 1));
    let spec = PolicySpec::from_config(&run.sac_config(tasks.len()));
    // TERL guidance (Eq. 15); `N` counts episodes since the first planner version, the actor's
    // or each environment's (`[guidance] episode_counter`).
    let guide = (run.algorithm == Algorithm::Terl).then(|| {
        let mut cfg = run.tep.clone();
        cfg.obs_dim = OBS_DIM;
        cfg.act_dim = ACTION_DIM;
        let v = env.inner();
        let targets = v
            .env_tasks()
            .iter()
            .map(|&k| GoalTarget::for_task(v.tasks()[k]))
            .collect();
        // The gate and the goal library index the run's task list.
        let env_tasks = v
            .env_tasks()
            .iter()
            .map(|&k| tasks.iter().position(|t| *t == v.tasks()[k]).unwrap_or(0) as u32)
            .collect();
        BatchGuidance::new(&cfg, run.guidance.sigma, targets)
            .with_counter(run.guidance.episode_counter)
            .with_tasks(env_tasks)
            .with_goal_source(run.guidance.goal_source)
    });
    anyhow::ensure!(
        !(run.cluster.reproducible && config.auto_id),
        "cluster.reproducible = true needs actors with fixed ids (--actor-id), not --actor-id auto"
    );
    let lockstep = run
        .cluster
        .reproducible
        .then(|| Lockstep::new(run, config.num_actors));
    let mut policy = ActorPolicy {
        policy: Policy::new(spec, num_envs),
        guide,
        mailbox,
        lockstep,
    };

    let transitions = transport.sink::<TransitionBatch>()?;
    let episodes = transport.sink::<EpisodeSummary>()?;
    tracing::info!(
        actor_id,
        tasks = ?my_names,
        envs = num_envs,
        "actor started; waiting for the learner and selector to subscribe"
    );
    let waiting = Instant::now();
    // A reproducible run cannot lose its first batches to nobody: it waits as long as it takes.
    while (transitions.receivers() < 1 || episodes.receivers() < 2)
        && (waiting.elapsed() < STARTUP_WAIT || lockstep.is_some())
    {
        if mailbox.stop.load(Ordering::Relaxed) {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(10));
    }

    let mut batch = TransitionBatch::EMPTY;
    batch.actor_id = actor_id;
    let start = Instant::now();
    let mut sink = ActorSink {
        transport,
        claim: &held,
        mailbox,
        transitions,
        episodes,
        actor_id,
        batch,
        sequence: 0,
        trajectories: (0..num_envs).map(|_| EpisodeSummary::empty()).collect(),
        episode_index: 0,
        closed: false,
        pauses: 0,
        paused: Duration::ZERO,
        log_at: start,
        log_steps: 0,
        dropped_seen: 0,
        checked_at: start,
    };
    let progress = if sink.check_learner() == Flow::Stop {
        RolloutProgress::default()
    } else {
        rollout::run(&mut env, &mut policy, &mut sink, seed)?
    };
    tracing::info!(
        actor_id,
        env_steps = progress.env_steps,
        env_steps_per_second = format!(
            "{:.0}",
            progress.env_steps as f64 / start.elapsed().as_secs_f64()
        ),
        policy_version = progress.policy_version,
        pauses_for_the_learner = sink.pauses,
        paused_secs = format!("{:.1}", sink.paused.as_secs_f64()),
        transition_batches_dropped = sink.transitions.stats().dropped,
        transitions_dropped = sink.transitions.stats().dropped_items,
        episodes_dropped = sink.episodes.stats().dropped,
        "actor stopped"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_transition_carries_the_record_its_version_and_its_flags() {
        let obs: Vec<f32> = (0..OBS_DIM).map(|k| k as f32).collect();
        let next_obs: Vec<f32> = (0..OBS_DIM).map(|k| -(k as f32)).collect();
        let action = [0.5, -0.5, 0.25, 1.0];
        let record = |truncated, success, guided| StepRecord {
            env: 3,
            task: 0,
            obs: &obs,
            action: &action,
            reward: 1.5,
            next_obs: &next_obs,
            terminated: false,
            truncated,
            success,
            guided,
            guidance: GuidanceStep::default(),
            policy_version: 7,
        };
        let t = transition_of(&record(false, false, false), 2, 5);
        assert_eq!(t.flags, 0);
        assert_eq!(
            (t.policy_version, t.actor_id, t.env_index, t.task),
            (7, 2, 3, 5)
        );
        assert_eq!((&t.obs[..], &t.next_obs[..]), (&obs[..], &next_obs[..]));
        assert_eq!((t.action, t.reward), (action, 1.5));
        let t = transition_of(&record(true, true, true), 2, 5);
        assert_eq!(
            t.flags,
            flags::TRUNCATED | flags::SUCCESS | flags::GUIDED,
            "{:b}",
            t.flags
        );
        assert_eq!(
            transition_of(&record(false, false, true), 2, 5).flags,
            flags::GUIDED
        );
        let mut step = record(false, false, true);
        step.guidance = GuidanceStep {
            active: true,
            probability: 0.9f64.powi(3),
            not_improving: Some(true),
            action_gap: Some(1.25),
        };
        let t = transition_of(&step, 2, 5);
        assert_eq!(
            t.flags,
            flags::GUIDED | flags::GUIDANCE_ACTIVE | flags::COMPARED | flags::NOT_IMPROVING
        );
        assert!((t.guidance_probability() - 0.729).abs() < 1e-4);
        assert!((t.action_gap() - 1.25).abs() < 1e-4);
        step.guided = false;
        step.guidance.not_improving = Some(false);
        step.guidance.action_gap = None;
        let t = transition_of(&step, 2, 5);
        assert_eq!(t.flags, flags::GUIDANCE_ACTIVE | flags::COMPARED);
        assert_eq!(t.action_gap(), 0.0);
        // Not active (no planner, or the task not validated): no σ^N is stamped.
        step.guidance = GuidanceStep {
            probability: 0.5,
            ..GuidanceStep::default()
        };
        let t = transition_of(&step, 2, 5);
        assert_eq!((t.flags, t.guidance_probability()), (0, 0.0));
    }

    /// The memory twin's sink for transitions, its transport (to add a receiver later) and a
    /// mailbox.
    fn link() -> (
        terl_transport::memory::MemoryTransport,
        terl_transport::memory::MemorySink<TransitionBatch>,
        std::sync::Arc<Mailbox>,
    ) {
        let t = terl_transport::memory::MemoryTransport::new(terl_transport::TransportConfig::new(
            "pause-test",
            1,
        ))
        .unwrap();
        let sink = t.memory_sink::<TransitionBatch>().unwrap();
        (t, sink, std::sync::Arc::default())
    }

    #[test]
    fn with_no_learner_the_actor_waits_with_back_off_until_stopped() {
        let (_t, sink, mailbox) = link();
        let stopper = {
            let mailbox = std::sync::Arc::clone(&mailbox);
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(1200));
                mailbox.stop.store(true, Ordering::Relaxed);
            })
        };
        let began = Instant::now();
        let mut cleanups = 0u32;
        let out = wait_for_learner(&sink, || cleanups += 1, &mailbox);
        let waited = began.elapsed();
        stopper.join().unwrap();
        assert_eq!(out, Rejoin::Stopped);
        // Checks at 0, 0.25, 0.75, 1.75 s, ...: with doubling waits, at most
        // 1 + log2(1 + waited / 0.25 s) checks fit in `waited` (a busy loop would make
        // thousands).
        let bound = 1.0 + (1.0 + waited.as_secs_f64() / 0.25).log2();
        assert!(
            cleanups >= 1 && f64::from(cleanups) <= bound.floor(),
            "{cleanups} checks in {waited:?} (bound {bound:.2})"
        );
    }

    #[test]
    fn the_actor_rejoins_once_the_learner_subscribes_and_sends_weights() {
        let (t, sink, mailbox) = link();
        // This actor had weights before the learner went away.
        mailbox.policy_posts.store(3, Ordering::Relaxed);
        let learner = {
            let mailbox = std::sync::Arc::clone(&mailbox);
            let t = t.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(300));
                let source = t.memory_source::<TransitionBatch>().unwrap();
                // Subscribed but no weights yet: the actor must keep waiting.
                std::thread::sleep(Duration::from_millis(400));
                let posted_at = Instant::now();
                mailbox.policy_posts.fetch_add(1, Ordering::Relaxed);
                (source, posted_at)
            })
        };
        let out = wait_for_learner(&sink, || {}, &mailbox);
        let returned_at = Instant::now();
        let (_source, posted_at) = learner.join().unwrap();
        assert!(matches!(out, Rejoin::Back { .. }), "{out:?}");
        assert!(
            returned_at >= posted_at,
            "returned before the new weights were posted"
        );
        assert_eq!(sink.receivers(), 1);
    }

    #[test]
    fn an_actor_without_weights_rejoins_a_fresh_learner_without_waiting_for_weights() {
        let (t, sink, mailbox) = link();
        let _source = t.memory_source::<TransitionBatch>().unwrap();
        // No weights were ever posted and none will be: a fresh learner publishes only after
        // its warm-up, which needs this actor's transitions.
        match wait_for_learner(&sink, || {}, &mailbox) {
            Rejoin::Back { waited, checks } => {
                assert_eq!(checks, 1);
                assert!(waited < REJOIN_WEIGHTS_WAIT, "{waited:?}");
            }
            other => panic!("{other:?}"),
        }
    }
}
