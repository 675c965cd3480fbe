//! The actor's environment loop (its own thread): act, step, batch transitions, send finished
//! episodes, load new weights between steps.

use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::Context;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use terl_rl::guidance::{BatchGuidance, GoalTarget};
use terl_rl::{Policy, PolicySpec};
use terl_runtime::{Algorithm, RunConfig};
use terl_sim::VecEnv;
use terl_transport::{
    flags, EpisodeSummary, Message, MessageSink, ServiceTransport, TrajectoryStep, Transition,
    TransitionBatch, TransportError, ACTION_DIM, OBS_DIM,
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

/// The transition environment `i` made in the last `env.step(actions)` from `obs` (the
/// observations acted on): `next_obs` is the observation the action reached — at the time limit
/// the episode's true last observation ([`VecEnv::final_obs`]), not the reset observation the
/// environment continues from. `None` when the step is not a transition of the task: the
/// physics went unstable ([`VecEnv::unstable`]), so the step is dropped (and counted by the
/// caller) rather than learned as an ordinary, bootstrapping transition with reward 0.
#[allow(clippy::too_many_arguments)]
pub(crate) fn transition_of(
    env: &VecEnv,
    i: usize,
    obs: &[f32],
    actions: &[f32],
    policy_version: u64,
    actor_id: u16,
    task: u16,
    guided: bool,
) -> Option<Transition> {
    if env.unstable()[i] {
        return None;
    }
    let truncated = env.truncated()[i];
    let next_obs = if truncated {
        env.final_obs()
    } else {
        env.obs()
    };
    let mut f = 0;
    if truncated {
        f |= flags::TRUNCATED;
    }
    if env.success()[i] {
        f |= flags::SUCCESS;
    }
    if guided {
        f |= flags::GUIDED;
    }
    Some(Transition {
        policy_version,
        obs: row(obs, i),
        next_obs: row(next_obs, i),
        action: row(actions, i),
        reward: env.rewards()[i],
        actor_id,
        env_index: i as u16,
        task,
        flags: f,
        reserved: [0; 5],
    })
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
    let (actor_id, _claim) = claim(transport, config)?;
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
    let mut env = VecEnv::new(&my_names, run.variation_seed)?;
    let seed = run
        .train
        .seed
        .wrapping_add(7919 * (u64::from(actor_id) + 1));
    env.reset_all_seeded(seed)?;
    let global_task: Vec<u16> = env
        .env_tasks()
        .iter()
        .map(|&k| {
            let name = env.tasks()[k];
            tasks
                .iter()
                .position(|t| *t == name)
                .expect("task of the run") as u16
        })
        .collect();
    let spec = PolicySpec {
        obs_dim: OBS_DIM,
        act_dim: ACTION_DIM,
        num_tasks: tasks.len(),
        hidden: run.sac.policy_hidden.clone(),
    };
    let mut policy = Policy::new(spec, num_envs);
    let policy_tasks: Vec<usize> = global_task.iter().map(|&t| usize::from(t)).collect();
    let env_task_names: Vec<&str> = env.env_tasks().iter().map(|&k| env.tasks()[k]).collect();
    // TERL guidance (Eq. 15); `N` counts episodes since the first planner version, the actor's
    // or each environment's (`[guidance] episode_counter`).
    let mut guide = (run.algorithm == Algorithm::Terl).then(|| {
        let mut cfg = run.tep.clone();
        cfg.obs_dim = OBS_DIM;
        cfg.act_dim = ACTION_DIM;
        let targets = env_task_names
            .iter()
            .map(|t| GoalTarget::for_task(t))
            .collect();
        BatchGuidance::new(&cfg, run.guidance.sigma, targets)
            .with_counter(run.guidance.episode_counter)
    });
    let mut rng = ChaCha8Rng::seed_from_u64(seed);

    let mut transitions = transport.sink::<TransitionBatch>()?;
    let mut episodes = transport.sink::<EpisodeSummary>()?;
    tracing::info!(
        actor_id,
        tasks = ?my_names,
        envs = num_envs,
        "actor started; waiting for the learner and selector to subscribe"
    );
    let waiting = Instant::now();
    while (transitions.receivers() < 1 || episodes.receivers() < 2)
        && waiting.elapsed() < STARTUP_WAIT
    {
        if mailbox.stop.load(Ordering::Relaxed) {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(10));
    }

    let (mut pauses, mut paused) = (0u64, Duration::ZERO);
    let mut batch = TransitionBatch::EMPTY;
    batch.actor_id = actor_id;
    let mut sequence = 0u64;
    let mut trajectories: Vec<Box<EpisodeSummary>> =
        (0..num_envs).map(|_| EpisodeSummary::empty()).collect();
    let mut episode_version = vec![0u64; num_envs];
    let mut episode_index = 0u64;
    let mut obs = env.obs().to_vec();
    let mut actions = vec![0.0f32; num_envs * ACTION_DIM];
    let (mut steps, mut episodes_done, mut successes) = (0u64, 0u64, 0u64);
    let mut guided_steps = 0u64;
    let mut unstable_steps = 0u64;
    let start = Instant::now();
    let (mut log_at, mut log_steps) = (start, 0u64);
    let (mut dropped_seen, mut checked_at) = (0u64, start);

    while !mailbox.stop.load(Ordering::Relaxed) {
        // A learner killed with SIGKILL leaves its subscription behind, and sends would fill
        // its queue and then block for `block_timeout_secs`: every second, and after any send
        // that timed out, remove dead processes' subscriptions, so that a dead learner shows
        // as no receiver.
        if transitions.stats().dropped > dropped_seen || checked_at.elapsed() >= LEARNER_CHECK_EVERY
        {
            dropped_seen = transitions.stats().dropped;
            checked_at = Instant::now();
            transport.cleanup_dead_nodes();
        }
        if transitions.receivers() == 0 {
            tracing::warn!(
                actor_id,
                "no learner receives transitions (stopped, killed or restarting): pausing the \
                 environments and checking for it with back-off"
            );
            match wait_for_learner(
                &*transitions,
                || {
                    transport.cleanup_dead_nodes();
                },
                mailbox,
            ) {
                Rejoin::Stopped => break,
                Rejoin::Back { waited, checks } => {
                    pauses += 1;
                    paused += waited;
                    tracing::info!(
                        actor_id,
                        waited_secs = format!("{:.1}", waited.as_secs_f64()),
                        checks,
                        newest_received = mailbox.received.load(Ordering::Relaxed),
                        "the learner is back; rejoining with its weights"
                    );
                }
            }
        }
        let fresh = mailbox.slot.lock().ok().and_then(|mut s| s.take());
        if let Some((version, params)) = fresh {
            match policy.set_params(&params, version) {
                Ok(()) => tracing::debug!(version, "loaded policy weights"),
                Err(e) => tracing::warn!(version, "ignoring policy weights: {e}"),
            }
        }
        if let Some(g) = guide.as_mut() {
            let fresh = mailbox.planner.lock().ok().and_then(|mut s| s.take());
            if let Some((version, f, an)) = fresh {
                match g.planner_mut().set_params(&f, &an, version) {
                    Ok(()) => tracing::debug!(version, "loaded planner weights"),
                    Err(e) => tracing::warn!(version, "ignoring planner weights: {e}"),
                }
            }
        }
        if policy.version == 0 {
            actions
                .iter_mut()
                .for_each(|a| *a = rng.gen_range(-1.0..1.0));
        } else {
            policy.act(&obs, &policy_tasks, false, &mut rng, &mut actions)?;
            if let Some(g) = guide.as_mut() {
                g.apply(&obs, &mut actions, &mut rng);
            }
        }
        env.step(&actions)?;
        for i in 0..num_envs {
            let guided = guide.as_ref().is_some_and(|g| g.guided()[i]);
            if guided {
                guided_steps += 1;
                trajectories[i].guided_steps = trajectories[i].guided_steps.saturating_add(1);
            }
            let Some(transition) = transition_of(
                &env,
                i,
                &obs,
                &actions,
                policy.version,
                actor_id,
                global_task[i],
                guided,
            ) else {
                unstable_steps += 1;
                continue;
            };
            let _ = trajectories[i].push_step(TrajectoryStep {
                obs: transition.obs,
                action: transition.action,
                reward: transition.reward,
            });
            if !batch.push(transition) {
                unreachable!("the batch is sent as soon as it is full");
            }
            if batch.is_full() {
                batch.sequence = sequence;
                if !send(transitions.as_mut(), &batch, mailbox)? {
                    return Ok(());
                }
                sequence += 1;
                batch.clear();
            }
        }
        for end in env.finished() {
            let i = end.env;
            if let Some(g) = guide.as_mut() {
                g.end_episode(i);
            }
            let episode = &mut trajectories[i];
            episode.policy_version = episode_version[i];
            episode.episode_index = episode_index;
            episode.episode_return = end.episode_return as f32;
            episode.length = end.length;
            episode.actor_id = actor_id;
            episode.env_index = i as u16;
            episode.task = global_task[i];
            episode.success = u8::from(end.success);
            episode.final_obs = row(env.final_obs(), i);
            if !send(episodes.as_mut(), &**episode, mailbox)? {
                return Ok(());
            }
            **episode = EpisodeSummary::EMPTY;
            episode_version[i] = policy.version;
            episode_index += 1;
            episodes_done += 1;
            successes += u64::from(end.success);
        }
        obs.copy_from_slice(env.obs());
        steps += num_envs as u64;

        if log_at.elapsed() >= LOG_EVERY {
            let rate = (steps - log_steps) as f64 / log_at.elapsed().as_secs_f64();
            tracing::info!(
                actor_id,
                env_steps = steps,
                env_steps_per_second = format!("{rate:.0}"),
                policy_version = policy.version,
                newest_received = mailbox.received.load(Ordering::Relaxed),
                episodes = episodes_done,
                successes,
                guided_steps,
                unstable_steps_dropped = unstable_steps,
                planner_version = guide.as_ref().map_or(0, |g| g.planner().version()),
                transitions = ?transitions.stats(),
                episode_sends = ?episodes.stats(),
                "progress"
            );
            (log_at, log_steps) = (Instant::now(), steps);
        }
    }
    tracing::info!(
        actor_id,
        env_steps = steps,
        env_steps_per_second = format!("{:.0}", steps as f64 / start.elapsed().as_secs_f64()),
        policy_version = policy.version,
        pauses_for_the_learner = pauses,
        paused_secs = format!("{:.1}", paused.as_secs_f64()),
        transition_batches_dropped = transitions.stats().dropped,
        transitions_dropped = transitions.stats().dropped_items,
        episodes_dropped = episodes.stats().dropped,
        "actor stopped"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_sim::metaworld::Env;

    fn action(step: usize) -> [f32; ACTION_DIM] {
        let t = step as f32 * 0.05;
        [t.sin(), t.cos(), (0.5 * t).sin(), 0.3]
    }

    #[test]
    fn the_time_limit_transition_carries_the_true_last_observation() {
        let mut env = VecEnv::new(&["push-v3", "reach-v3"], 3).unwrap();
        env.reset_all_seeded(5).unwrap();
        // Second path: the same episode replayed on a plain `Env` from the same variation.
        let mut single = Env::new("push-v3").unwrap();
        single.reset(env.env(0).rand_vec()).unwrap();
        let mut obs = env.obs().to_vec();
        for step in 0..500 {
            let a = action(step);
            let actions: Vec<f32> = a.iter().chain(&a).copied().collect();
            env.step(&actions).unwrap();
            let expected = single.step(&a).unwrap();
            let t = transition_of(&env, 0, &obs, &actions, 7, 1, 0, false).unwrap();
            let truncated = step == 499;
            assert_eq!(env.truncated()[0], truncated);
            assert_eq!(t.flags & flags::TRUNCATED != 0, truncated);
            for (k, (&got, &want)) in t.next_obs.iter().zip(&expected.obs).enumerate() {
                assert!(
                    (f64::from(got) - want).abs() < 1e-5,
                    "step {step} obs[{k}]: transition {got}, replayed env {want}"
                );
            }
            if truncated {
                // The environment already continues from a reset observation; the transition
                // does not carry it.
                assert_ne!(&t.next_obs[..], &env.obs()[..39]);
                assert_eq!(&t.next_obs[..], &env.final_obs()[..39]);
            }
            obs.copy_from_slice(env.obs());
        }
    }

    #[test]
    fn a_physics_blow_up_is_dropped_not_sent_as_a_transition() {
        let mut env = VecEnv::new(&["reach-v3", "push-v3"], 0).unwrap();
        env.reset_all_seeded(1).unwrap();
        let a = action(0);
        let actions: Vec<f32> = a.iter().chain(&a).copied().collect();
        env.step(&actions).unwrap();
        let obs = env.obs().to_vec();
        env.env_mut(1).inject_nan_velocity();
        env.step(&actions).unwrap();
        assert!(env.unstable()[1] && !env.unstable()[0]);
        assert!(transition_of(&env, 1, &obs, &actions, 1, 0, 1, false).is_none());
        assert!(transition_of(&env, 0, &obs, &actions, 1, 0, 0, false).is_some());
        // The environment was reset and steps normally again.
        env.step(&actions).unwrap();
        assert!(!env.unstable()[1]);
        assert!(transition_of(&env, 1, &obs, &actions, 1, 0, 1, false).is_some());
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
