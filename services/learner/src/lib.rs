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
//! Two halves: the training loop ([`trainer`]) is CPU-bound and runs on its own thread; the
//! gRPC server runs on the tokio runtime of the caller. They share a status snapshot the
//! trainer refreshes a few times a second, the [`WeightHub`], and a checkpoint-request channel.
//! `run` returns when `shutdown` completes (or the trainer fails), after the trainer thread has
//! written its final checkpoint and dropped its shared-memory node.

mod dataset;
mod metrics;
mod planner;
mod trainer;

use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Instant;

use anyhow::Context;
use terl_wire::{CheckpointRequest, CheckpointSaved, LearnerBackend, LearnerStatus, WeightHub};
use tonic::Status;

pub use trainer::CheckpointJob;

/// Everything the learner needs to start.
pub type LearnerConfig = terl_runtime::ServiceConfig;

/// State shared between the trainer thread and the gRPC service.
#[derive(Debug)]
pub(crate) struct Shared {
    pub(crate) started: Instant,
    pub(crate) status: Mutex<LearnerStatus>,
    pub(crate) stop: AtomicBool,
}

#[derive(Debug)]
struct Backend {
    shared: Arc<Shared>,
    hub: WeightHub,
    checkpoints: Mutex<mpsc::Sender<CheckpointJob>>,
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

/// Runs the learner until `shutdown` completes or the trainer fails.
pub async fn run(
    config: LearnerConfig,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    let listener = terl_wire::bind_secured(config.addr, &config.server_security)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let serve_options = terl_wire::ServeOptions {
        security: config.server_security.clone(),
        ..terl_wire::ServeOptions::default()
    };
    let addr = listener.local_addr()?;
    let addr_file = terl_runtime::write_addr_file(&config.run_dir, "learner", addr)?;
    tracing::info!(%addr, file = %addr_file.display(), run_id = %config.run_id, "learner listening");

    let shared = Arc::new(Shared {
        started: Instant::now(),
        status: Mutex::new(LearnerStatus {
            run_id: config.run_id.clone(),
            ..LearnerStatus::default()
        }),
        stop: AtomicBool::new(false),
    });
    let hub = WeightHub::new();
    let (checkpoint_tx, checkpoint_rx) = mpsc::channel();
    let (done_tx, mut done_rx) = tokio::sync::watch::channel(false);
    let trainer = {
        let (shared, hub) = (Arc::clone(&shared), hub.clone());
        std::thread::Builder::new()
            .name("trainer".into())
            .spawn(move || {
                let result = trainer::run(&config, &shared, &hub, &checkpoint_rx);
                let _ = done_tx.send(true);
                result
            })?
    };
    let backend = Backend {
        shared: Arc::clone(&shared),
        hub,
        checkpoints: Mutex::new(checkpoint_tx),
    };
    let stop_serving = async {
        tokio::select! {
            () = shutdown => {}
            _ = done_rx.wait_for(|done| *done) => tracing::info!("trainer stopped; shutting down"),
        }
    };
    let served =
        terl_wire::serve_learner_with(listener, backend, stop_serving, serve_options).await;
    shared.stop.store(true, Ordering::Relaxed);
    let trained = tokio::task::spawn_blocking(move || trainer.join())
        .await?
        .map_err(|_| anyhow::anyhow!("trainer thread panicked"))?;
    served.context("gRPC server")?;
    trained
}
