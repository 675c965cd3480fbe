//! The learner service: drains actors' transitions from shared memory into per-task replay,
//! runs MTSAC updates at the configured update-to-data ratio, publishes policy weights every
//! K updates to the `WatchWeights` streams, writes periodic safetensors checkpoints, and
//! answers `GetStatus`/`SaveCheckpoint` over gRPC.
//!
//! With `algorithm = "terl"` it also keeps the TEP buffer (selected samples from the selector,
//! optionally started from an earlier run's dataset), interleaves TEP updates with the SAC
//! updates, publishes the planner (and, for the selector's PTR scoring, the critics) on the
//! same weight stream, and reports TEP losses and the guidance rate per task.
//!
//! Transitions, episodes and selections that senders could not deliver (the learner stalled
//! longer than `[cluster] block_timeout_secs`) are reported in the status and the metrics log
//! from the loss stamps on what does arrive (see `losses`).
//!
//! Two halves: the training loop (`trainer`) is CPU-bound and runs on its own thread; the
//! gRPC server runs on the tokio runtime of the caller. They share a status snapshot the
//! trainer refreshes a few times a second, the [`WeightHub`], and a checkpoint-request channel.
//! `run` returns when `shutdown` completes (or the trainer fails), after the trainer thread has
//! written its final checkpoint and dropped its shared-memory node.

#![warn(missing_docs)]

pub mod args;
mod checkpoint;
mod checkpointing;
mod dataset;
mod lockstep;
mod losses;
mod metrics;
mod planner;
mod publisher;
mod staging;
mod status;
mod trainer;

use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Instant;

use anyhow::Context;
use terl_wire::{CheckpointRequest, CheckpointSaved, LearnerBackend, LearnerStatus, WeightHub};
use tonic::Status;
use tracing::Instrument;

pub use checkpointing::CheckpointJob;

/// Everything the learner needs to start.
pub type LearnerConfig = terl_runtime::ServiceConfig;

/// State shared between the trainer thread and the gRPC service.
#[derive(Debug)]
pub(crate) struct Shared {
    pub(crate) started: Instant,
    pub(crate) status: Mutex<LearnerStatus>,
    pub(crate) stop: AtomicBool,
    /// Timed before the address is announced ([`trainer::calibrate`]); 0 when skipped.
    pub(crate) standalone_updates_per_second: f64,
}

#[derive(Debug)]
struct Backend {
    shared: Arc<Shared>,
    hub: WeightHub,
    checkpoints: Mutex<mpsc::Sender<CheckpointJob>>,
    /// The run's actor count (`--num-actors`): the ids a weight watcher may name.
    actors: u32,
}

impl LearnerBackend for Backend {
    async fn status(&self) -> Result<LearnerStatus, Status> {
        let mut status = self
            .shared
            .status
            .lock()
            .map_err(|_| Status::internal("status lock poisoned"))?
            .clone();
        status.uptime_seconds = self.shared.started.elapsed().as_secs_f64();
        Ok(status)
    }

    async fn save_checkpoint(&self, request: CheckpointRequest) -> Result<CheckpointSaved, Status> {
        let (reply, answer) = tokio::sync::oneshot::channel();
        self.checkpoints
            .lock()
            .map_err(|_| Status::internal("checkpoint channel lock poisoned"))?
            .send(CheckpointJob { request, reply })
            .map_err(|_| Status::unavailable("the trainer has stopped"))?;
        answer
            .await
            .map_err(|_| Status::unavailable("the trainer stopped before saving"))?
            .map_err(Status::internal)
    }

    fn weight_hub(&self) -> &WeightHub {
        &self.hub
    }

    fn actor_slots(&self) -> Option<u32> {
        Some(self.actors)
    }
}

/// Named `f32` tensors of a network as a weight-stream message.
pub(crate) fn to_weights(
    kind: terl_wire::WeightsKind,
    version: u64,
    learner_update: u64,
    tensors: Vec<terl_nn::tensors::Tensor>,
) -> anyhow::Result<terl_wire::Weights> {
    let tensors = tensors
        .into_iter()
        .map(|t| {
            let values = t.values::<f32>()?;
            Ok(terl_wire::Tensor::new(t.name, t.shape, values)?)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    Ok(terl_wire::Weights::new(
        kind,
        version,
        learner_update,
        tensors,
    )?)
}

/// Start-up checks that need neither a listener nor a transport: the task list resolves and
/// the networks' weights fit a gRPC message (refused naming the run-file key that raises the
/// limit, rather than at the first publication after minutes of training). The binary calls
/// it before it listens; [`run`] calls it again before it announces its address.
///
/// # Errors
/// An unknown task, or a weight message over `[cluster] max_message_mib`.
pub fn check_start_up(config: &LearnerConfig) -> anyhow::Result<()> {
    let num_tasks = terl_runtime::resolve_tasks(&config.run.tasks)?.len();
    config.run.check_weight_messages(num_tasks)?;
    Ok(())
}

/// Runs the learner on `listener` (already bound, e.g. by [`terl_wire::bind_secured`]) and
/// `transport` (the run's streams: [`terl_transport::RunTransport`] in the binary, a
/// [`terl_transport::MemoryTransport`] on a shared bus in tests) until `shutdown` completes or
/// the trainer stops (training budget reached, or an error). Writes `<run_dir>/learner.addr`;
/// logs inside a `learner{run=<run id>}` span.
///
/// # Errors
/// A failed start-up check (before the address file is written), the trainer's error, or the
/// gRPC server's.
pub async fn run<T: terl_transport::ServiceTransport>(
    config: LearnerConfig,
    listener: tokio::net::TcpListener,
    transport: T,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    let span = tracing::info_span!("learner", run = %config.run_id);
    run_in_span(config, listener, transport, shutdown, span.clone())
        .instrument(span)
        .await
}

async fn run_in_span<T: terl_transport::ServiceTransport>(
    config: LearnerConfig,
    listener: tokio::net::TcpListener,
    transport: T,
    shutdown: impl Future<Output = ()> + Send,
    span: tracing::Span,
) -> anyhow::Result<()> {
    check_start_up(&config)?;
    let max_message_bytes = config.run.cluster.max_message_bytes();
    let serve_options = terl_wire::ServeOptions {
        max_message_bytes,
        security: config.server_security.clone(),
        ..terl_wire::ServeOptions::default()
    };
    if let Some(found) = finished_before(&config)? {
        tracing::info!(
            checkpoint = %found.path.display(),
            env_steps = found.state.env_steps,
            budget = config.run.train.total_env_steps,
            updates = found.updates,
            "the run is already finished (train.total_env_steps reached): nothing to train, no \
             checkpoint, metrics or dataset file written"
        );
        if !config.idle_when_finished {
            return Ok(());
        }
        let status = LearnerStatus {
            run_id: config.run_id.clone(),
            updates: found.updates,
            env_steps_total: found.state.env_steps,
            policy_version: found.state.policy_version,
            algorithm: found.state.algorithm.clone(),
            ..LearnerStatus::default()
        };
        let shared = Arc::new(Shared {
            started: Instant::now(),
            status: Mutex::new(status),
            stop: AtomicBool::new(true),
            standalone_updates_per_second: 0.0,
        });
        terl_runtime::service::announce(&listener, &config.run_dir, "learner", &config.run_id)?;
        return serve_finished(
            &config,
            listener,
            shared,
            WeightHub::new(),
            shutdown,
            serve_options,
        )
        .await;
    }
    // Timed before the address appears: a launcher starts the selector and the actors only
    // once it has, so the learner is timed alone.
    let standalone = {
        let config = config.clone();
        tokio::task::spawn_blocking(move || trainer::calibrate(&config))
            .await
            .context("timing the standalone update rate")??
    };
    let shared = Arc::new(Shared {
        started: Instant::now(),
        status: Mutex::new(LearnerStatus {
            run_id: config.run_id.clone(),
            ..LearnerStatus::default()
        }),
        stop: AtomicBool::new(false),
        standalone_updates_per_second: standalone,
    });
    let hub = WeightHub::with_max_message_bytes(max_message_bytes);
    let actors = u32::try_from(config.num_actors).unwrap_or(u32::MAX);
    let (checkpoint_tx, checkpoint_rx) = mpsc::channel();
    let (opened_tx, opened_rx) = tokio::sync::oneshot::channel();
    let mut trainer = {
        let (shared, hub, config) = (Arc::clone(&shared), hub.clone(), config.clone());
        terl_runtime::service::Worker::spawn("trainer", "trainer thread", span, move || {
            trainer::run(
                &config,
                &transport,
                &shared,
                &hub,
                &checkpoint_rx,
                opened_tx,
            )
        })?
    };
    // The address appears once the trainer holds the run's streams: a second learner of a
    // run fails here and leaves the live learner's address file alone.
    if opened_rx.await.is_err() {
        trainer.join().await?;
        anyhow::bail!("the trainer stopped before it opened the run's streams");
    }
    let (announced, _) =
        terl_runtime::service::announce(&listener, &config.run_dir, "learner", &config.run_id)?;
    let backend = Backend {
        shared: Arc::clone(&shared),
        hub: hub.clone(),
        checkpoints: Mutex::new(checkpoint_tx),
        actors,
    };
    // Fused: after training ends, `--when-finished idle` waits on the same signal.
    let mut shutdown = std::pin::pin!(futures_util::FutureExt::fuse(shutdown));
    let served = terl_runtime::service::serve_until(shutdown.as_mut(), &mut trainer, |stop| {
        terl_wire::serve_learner_with(listener, backend, stop, serve_options.clone())
    })
    .await;
    shared.stop.store(true, Ordering::Relaxed);
    let trained = trainer.join().await;
    served.context("gRPC server")?;
    trained?;
    // The trainer ends without an error only when the run is finished or it was told to stop.
    if config.idle_when_finished && !futures_util::future::FusedFuture::is_terminated(&shutdown) {
        let listener = terl_wire::bind_secured(announced, &config.server_security)
            .await
            .with_context(|| format!("cannot listen on {announced} again"))?;
        return serve_finished(&config, listener, shared, hub, shutdown, serve_options).await;
    }
    Ok(())
}

/// With `--resume`, the newest intact checkpoint when the run is finished under the run file as
/// it is now: it has reached the env-step budget, or it is the final checkpoint of a stage-1 run
/// that stopped because its planner was ready (recorded in it) and the run file still asks for
/// that stop. Nothing is then to be done; a raised budget (or a removed stop) continues the run.
fn finished_before(config: &LearnerConfig) -> anyhow::Result<Option<checkpoint::Found>> {
    if !config.resume {
        return Ok(None);
    }
    let budget = config.run.train.total_env_steps;
    let planner_stop = config.run.cluster.stop_at_planner_samples_per_task > 0;
    let found = checkpoint::newest_intact(&config.run_dir.join("checkpoints"))?;
    Ok(found.filter(|f| {
        (budget > 0 && f.state.env_steps >= budget)
            || (planner_stop && f.state.finished.as_deref() == Some("planner_ready"))
    }))
}

/// A finished run's learner under `--when-finished idle`: answers status (the final counters)
/// until `shutdown`, and streams what `hub` holds (the last published weights when the trainer
/// of this process reached the budget; nothing for a run found finished at start); trains and
/// writes nothing.
async fn serve_finished(
    config: &LearnerConfig,
    listener: tokio::net::TcpListener,
    shared: Arc<Shared>,
    hub: WeightHub,
    shutdown: impl Future<Output = ()> + Send,
    serve_options: terl_wire::ServeOptions,
) -> anyhow::Result<()> {
    tracing::info!(
        addr = %listener.local_addr()?,
        "the run is finished; answering status until stopped (--when-finished idle)"
    );
    // No trainer: a checkpoint request is answered "unavailable".
    let (checkpoint_tx, _) = mpsc::channel();
    let backend = Backend {
        shared,
        hub,
        checkpoints: Mutex::new(checkpoint_tx),
        actors: u32::try_from(config.num_actors).unwrap_or(u32::MAX),
    };
    terl_wire::serve_learner_with(listener, backend, shutdown, serve_options)
        .await
        .context("gRPC server")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Networks whose weights would not fit a gRPC message stop the learner before it listens
    /// or allocates them, naming the run-file key that raises the limit; the encoded size of a
    /// real policy message stays within the bound the check uses.
    #[test]
    fn weights_over_the_message_limit_are_refused_at_start_up() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.toml");
        std::fs::write(
            &path,
            "tasks = \"mt10\"\nnum_envs = 10\n[sac]\npolicy_hidden = [4096, 4096, 4096]\n",
        )
        .unwrap();
        let run_config = terl_runtime::RunConfig::load(&path).unwrap();
        let config = LearnerConfig::new(
            run_config,
            format!("msg-limit-{}", std::process::id()),
            "127.0.0.1:0".parse().unwrap(),
            1,
            dir.path().join("run"),
        );
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        assert!(check_start_up(&config).is_err());
        let transport = terl_transport::MemoryTransport::new(
            config
                .run
                .cluster
                .transport_config(config.run_id.as_str(), 1),
        )
        .unwrap();
        let e = rt
            .block_on(async {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
                super::run(config, listener, transport, std::future::pending()).await
            })
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("policy weights message") && e.contains("max_message_mib = 129"),
            "{e}"
        );
        assert!(!dir.path().join("run").join("learner.addr").exists());

        // The bound against a real message of a small policy, MTSAC's and CARE's (whose
        // message also carries its experts, attention, task encoder and context table).
        let care = terl_rl::CareConfig {
            context: terl_rl::CareContext::OneHot,
            ..terl_rl::CareConfig::default()
        };
        for care in [None, Some(care)] {
            let mut sac_config = terl_rl::SacConfig {
                num_tasks: 10,
                policy_hidden: vec![64, 32],
                care,
                ..terl_rl::SacConfig::default()
            };
            sac_config.batch_size = 8;
            let sac = terl_rl::Sac::<f32>::new(sac_config.clone()).unwrap();
            let weights =
                to_weights(terl_wire::WeightsKind::Policy, 1, 0, sac.policy_tensors()).unwrap();
            let encoded =
                prost::Message::encoded_len(&terl_wire::pb::WeightsUpdate::from(&weights));
            let mut cfg = terl_runtime::RunConfig::load(&path).unwrap();
            cfg.sac = sac_config;
            let bound = cfg.weight_message_bytes(10)[0].1;
            assert!(
                encoded as u64 <= bound && bound < encoded as u64 + 4096,
                "CARE {}: encoded {encoded}, bound {bound}",
                cfg.sac.care.is_some()
            );
        }
    }
}
