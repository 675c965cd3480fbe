//! The actor service: `E` Meta-World environments of this actor's share of the tasks, acting
//! with the newest policy the learner streams (`WatchWeights`; uniform random actions until
//! the first version arrives), sending transitions in batches and finished episodes over
//! shared memory. Every transition carries the policy version that chose its action.
//!
//! The environment loop is CPU-bound and runs on its own thread; the weight stream is a tokio
//! task that reconnects when the learner goes away and hands the newest version to the loop
//! through a one-slot mailbox (latest wins: the loop never waits for weights).

mod envloop;

use std::future::Future;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::StreamExt;
use terl_runtime::RunConfig;
use terl_wire::WeightsKind;

/// Everything an actor needs to start.
#[derive(Debug, Clone)]
pub struct ActorConfig {
    pub run: RunConfig,
    pub run_id: String,
    pub actor_id: usize,
    pub num_actors: usize,
    /// The learner's gRPC address (`host:port`).
    pub learner_addr: String,
}

impl ActorConfig {
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
            num_actors,
            learner_addr,
        }
    }
}

/// The newest policy version received and not yet loaded: `(version, flat parameters)`.
#[derive(Debug, Default)]
pub(crate) struct Mailbox {
    pub(crate) slot: Mutex<Option<(u64, Vec<f32>)>>,
    /// Newest version received (for logs).
    pub(crate) received: AtomicU64,
    pub(crate) stop: AtomicBool,
}

/// Follows the learner's policy stream forever, reconnecting after failures.
async fn follow_weights(addr: String, mailbox: Arc<Mailbox>) {
    let mut logged_wait = false;
    loop {
        match terl_wire::connect_learner(&addr).await {
            Ok(mut client) => match client.watch_weights(&[WeightsKind::Policy]).await {
                Ok(mut stream) => {
                    tracing::info!(%addr, "following the learner's policy weights");
                    logged_wait = false;
                    while let Some(item) = stream.next().await {
                        match item {
                            Ok(weights) => {
                                let version = weights.version();
                                let flat: Vec<f32> = weights
                                    .into_tensors()
                                    .into_iter()
                                    .flat_map(|t| t.into_parts().2)
                                    .collect();
                                mailbox.received.store(version, Ordering::Relaxed);
                                if let Ok(mut slot) = mailbox.slot.lock() {
                                    *slot = Some((version, flat));
                                }
                            }
                            Err(status) => {
                                tracing::warn!(%status, "weights stream error");
                                break;
                            }
                        }
                    }
                }
                Err(status) => tracing::warn!(%status, "WatchWeights refused"),
            },
            Err(e) => {
                if !logged_wait {
                    tracing::info!("waiting for the learner: {e}");
                    logged_wait = true;
                }
            }
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
}

/// Runs the actor until `shutdown` completes or the environment loop fails.
pub async fn run(
    config: ActorConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        config.actor_id < config.num_actors,
        "actor id {} must be below the number of actors {}",
        config.actor_id,
        config.num_actors
    );
    let mailbox = Arc::new(Mailbox::default());
    let follower = tokio::spawn(follow_weights(
        config.learner_addr.clone(),
        Arc::clone(&mailbox),
    ));
    let (done_tx, mut done_rx) = tokio::sync::watch::channel(false);
    let env_thread = {
        let mailbox = Arc::clone(&mailbox);
        std::thread::Builder::new()
            .name("envs".into())
            .spawn(move || {
                let result = envloop::run(&config, &mailbox);
                let _ = done_tx.send(true);
                result
            })?
    };
    tokio::select! {
        () = shutdown => {}
        _ = done_rx.wait_for(|done| *done) => {}
    }
    mailbox.stop.store(true, Ordering::Relaxed);
    follower.abort();
    tokio::task::spawn_blocking(move || env_thread.join())
        .await?
        .map_err(|_| anyhow::anyhow!("environment thread panicked"))?
}
