//! The actor service: `E` Meta-World environments of this actor's share of the tasks, acting
//! with the newest policy the learner streams (`WatchWeights`; uniform random actions until
//! the first version arrives), sending transitions in batches and finished episodes over
//! shared memory. Every transition carries the policy version that chose its action.
//!
//! With `algorithm = "terl"` the actor also follows the planner weights and applies TERL
//! guidance (Eq. 15): when F says the policy's action does not bring the goal state closer than
//! the previous step's did, it executes the Action Network's action with probability `σ^N`;
//! such transitions carry the `GUIDED` flag (the learner reports the rate per task).
//!
//! An actor claims its id on the run at start-up (see
//! `terl_transport::ShmTransport::claim_actor_id`): a second process with an id that is already
//! streaming is refused with an error naming the id and the run. A send that times out on a
//! full receiver (`[cluster] block_timeout_secs`) drops that batch or episode; the transport
//! counts it and stamps the running totals on the next message, so the learner and the selector
//! report it.
//!
//! The environment loop is CPU-bound and runs on its own thread; the weight stream is a tokio
//! task that reconnects when the learner goes away and hands the newest version to the loop
//! through one-slot mailboxes (latest wins: the loop never waits for weights).

#![warn(missing_docs)]

pub mod args;
mod envloop;

use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use terl_rl::names;
use terl_runtime::{Algorithm, RunConfig};
use terl_wire::{Weights, WeightsKind};
use tracing::Instrument;

/// Everything an actor needs to start.
#[derive(Debug, Clone)]
pub struct ActorConfig {
    /// The run file.
    pub run: RunConfig,
    /// The run's id: names its shared-memory services (`terl/<run_id>/...`) and appears in logs.
    pub run_id: String,
    /// This actor's id, below `num_actors` (ignored with `auto_id`).
    pub actor_id: usize,
    /// Take the lowest actor id no live actor of the run holds, and step every task (for
    /// replicas of one Kubernetes Deployment, which cannot be told apart). `num_actors` is then
    /// the most actors the run takes.
    pub auto_id: bool,
    /// Actor processes of the run: sizes the transport and, with a fixed id, splits the
    /// environments' tasks among the actors.
    pub num_actors: usize,
    /// The learner's gRPC address (`host:port`).
    pub learner_addr: String,
    /// Token and TLS trust for the learner's weight stream (default: none); the binary fills
    /// it from `[cluster]` and `TERL_TOKEN` ([`RunConfig`]'s `cluster.client_security`).
    pub client_security: terl_wire::ClientSecurity,
}

impl ActorConfig {
    /// A config with a fixed `actor_id`, no `auto_id` and no token or TLS.
    pub fn new(
        run: RunConfig,
        run_id: String,
        actor_id: usize,
        num_actors: usize,
        learner_addr: String,
    ) -> Self {
        Self {
            run,
            run_id,
            actor_id,
            auto_id: false,
            num_actors,
            learner_addr,
            client_security: terl_wire::ClientSecurity::default(),
        }
    }
}

/// Planner weights received and not yet loaded.
#[derive(Debug)]
pub(crate) struct PlannerParams {
    pub(crate) version: u64,
    /// F's and AN's flat parameters.
    pub(crate) f: Vec<f32>,
    pub(crate) an: Vec<f32>,
    /// The guidance gate, one flag per task of the run (`None`: a learner without a gate).
    pub(crate) gate: Option<Vec<bool>>,
    /// The goal library of the final-state goal source.
    pub(crate) goals: Option<terl_rl::guidance::GoalLibrary>,
}

/// The newest weights received and not yet loaded.
#[derive(Debug, Default)]
pub(crate) struct Mailbox {
    /// Policy: `(version, flat parameters)`.
    pub(crate) slot: Mutex<Option<(u64, Vec<f32>)>>,
    pub(crate) planner: Mutex<Option<PlannerParams>>,
    /// Newest version received (for logs).
    pub(crate) received: AtomicU64,
    /// Policy versions posted so far (a resumed learner may republish a version number the
    /// actor has seen, so rejoining waits on this count, not on the version).
    pub(crate) policy_posts: AtomicU64,
    pub(crate) stop: AtomicBool,
    /// Transition batches this actor has sent (the index of the batch being filled), which a
    /// reproducible run's policy version is fixed by.
    pub(crate) sent_batches: AtomicU64,
}

/// Hands one received weight version to the environment loop's mailbox.
fn post(mailbox: &Mailbox, weights: Weights) {
    let (kind, version) = (weights.kind(), weights.version());
    match kind {
        WeightsKind::Planner => {
            let (mut f, mut an) = (Vec::new(), Vec::new());
            let (mut gate, mut goal_tasks, mut goal_states) = (None, None, None);
            for t in weights.into_tensors() {
                let (name, _, values) = t.into_parts();
                if name == names::TEP_GATE {
                    gate = Some(values.iter().map(|&v| v > 0.5).collect());
                } else if name == names::TEP_GOAL_TASKS {
                    goal_tasks = Some(values);
                } else if name == names::TEP_GOAL_STATES {
                    goal_states = Some(values);
                } else if names::belongs_to(&name, names::TEP_F) {
                    f.extend(values);
                } else if names::belongs_to(&name, names::TEP_AN) {
                    an.extend(values);
                }
            }
            let goals = match (goal_tasks, goal_states) {
                (Some(tasks), Some(states))
                    if states.len() == tasks.len() * terl_transport::OBS_DIM
                        && tasks.iter().all(|t| t.is_finite() && *t >= 0.0)
                        && states.iter().all(|v| v.is_finite()) =>
                {
                    let mut lib = terl_rl::guidance::GoalLibrary::new(terl_transport::OBS_DIM);
                    for (k, s) in tasks
                        .iter()
                        .zip(states.chunks_exact(terl_transport::OBS_DIM))
                    {
                        lib.push(*k as u32, s);
                    }
                    Some(lib)
                }
                (None, None) => None,
                _ => {
                    tracing::warn!(version, "ignoring a malformed goal library");
                    None
                }
            };
            if let Ok(mut slot) = mailbox.planner.lock() {
                *slot = Some(PlannerParams {
                    version,
                    f,
                    an,
                    gate,
                    goals,
                });
            }
        }
        _ => {
            let flat: Vec<f32> = weights.into_flat();
            mailbox.received.store(version, Ordering::Relaxed);
            mailbox.policy_posts.fetch_add(1, Ordering::Relaxed);
            if let Ok(mut slot) = mailbox.slot.lock() {
                *slot = Some((version, flat));
            }
        }
    }
}

/// Runs the actor on `transport` (the run's streams: [`terl_transport::RunTransport`] in the
/// binary, a [`terl_transport::MemoryTransport`] on a shared bus in tests) until `shutdown`
/// completes or the environment loop fails. Follows the learner's weights at
/// `config.learner_addr` once it holds its actor id; logs inside an `actor{id=<actor id>}`
/// span (with `auto_id`, the id is filled in once taken).
///
/// # Errors
/// An actor id at or above `num_actors`, an id another live actor holds, or the environment
/// loop's error.
pub async fn run<T: terl_transport::ServiceTransport>(
    config: ActorConfig,
    transport: T,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    let span = if config.auto_id {
        tracing::info_span!("actor", id = tracing::field::Empty)
    } else {
        tracing::info_span!("actor", id = config.actor_id)
    };
    run_in_span(config, transport, shutdown, span.clone())
        .instrument(span)
        .await
}

async fn run_in_span<T: terl_transport::ServiceTransport>(
    config: ActorConfig,
    transport: T,
    shutdown: impl Future<Output = ()> + Send,
    span: tracing::Span,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        config.auto_id || config.actor_id < config.num_actors,
        "actor id {} must be below the number of actors {}",
        config.actor_id,
        config.num_actors
    );
    let mailbox = Arc::new(Mailbox::default());
    let kinds = match config.run.algorithm {
        Algorithm::Mtsac | Algorithm::Care => vec![WeightsKind::Policy],
        Algorithm::Terl => vec![WeightsKind::Policy, WeightsKind::Planner],
    };
    let (claimed_tx, claimed_rx) = tokio::sync::oneshot::channel();
    let max_message_bytes = config.run.cluster.max_message_bytes();
    let (learner_addr, security) = (config.learner_addr.clone(), config.client_security.clone());
    let mut env_thread = {
        let mailbox = Arc::clone(&mailbox);
        terl_runtime::service::Worker::spawn("envs", "environment thread", span, move || {
            envloop::run(&config, &transport, &mailbox, claimed_tx)
        })?
    };
    // Weights are followed once the actor holds its id, under which the learner lists it.
    let follow = |actor_id: usize| {
        let mailbox = Arc::clone(&mailbox);
        let options = terl_wire::ClientOptions {
            max_message_bytes,
            security: security.clone(),
            watcher: Some(terl_wire::Watcher {
                actor_id: actor_id as u32,
                host: terl_runtime::host_name(),
            }),
        };
        tokio::spawn(
            terl_wire::follow_weights_with(
                learner_addr.clone(),
                kinds.clone(),
                options,
                move |w| post(&mailbox, w),
            )
            .in_current_span(),
        )
    };
    tokio::pin!(shutdown);
    let claimed = tokio::select! {
        () = &mut shutdown => None,
        () = env_thread.stopped() => None,
        Ok(actor_id) = claimed_rx => Some(actor_id),
    };
    let follower = claimed.map(follow);
    if follower.is_some() {
        tokio::select! {
            () = &mut shutdown => {}
            () = env_thread.stopped() => {}
        }
    }
    mailbox.stop.store(true, Ordering::Relaxed);
    if let Some(follower) = follower {
        follower.abort();
    }
    env_thread.join().await
}
