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
//! Two halves: the training loop ([`trainer`]) is CPU-bound and runs on its own thread; the
//! gRPC server runs on the tokio runtime of the caller. They share a status snapshot the
//! trainer refreshes a few times a second, the [`WeightHub`], and a checkpoint-request channel.
//! `run` returns when `shutdown` completes (or the trainer fails), after the trainer thread has
//! written its final checkpoint and dropped its shared-memory node.

mod checkpoint;
mod dataset;
mod losses;
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
    // Weights that would not fit a gRPC message fail here, naming the run-file key, rather than
    // at the first publication after minutes of training.
    let num_tasks = terl_runtime::resolve_tasks(&config.run.tasks)?.len();
    config.run.check_weight_messages(num_tasks)?;
    let max_message_bytes = config.run.cluster.max_message_bytes();
    let listener = terl_wire::bind_secured(config.addr, &config.server_security)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let serve_options = terl_wire::ServeOptions {
        max_message_bytes,
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
    let hub = WeightHub::with_max_message_bytes(max_message_bytes);
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
        let e = rt
            .block_on(super::run(config, std::future::pending()))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("policy weights message") && e.contains("max_message_mib = 129"),
            "{e}"
        );
        assert!(!dir.path().join("run").join("learner.addr").exists());

        // The bound against a real message of a small policy.
        let mut sac_config = terl_rl::SacConfig {
            num_tasks: 10,
            policy_hidden: vec![64, 32],
            ..terl_rl::SacConfig::default()
        };
        sac_config.batch_size = 8;
        let sac = terl_rl::Sac::<f32>::new(sac_config.clone()).unwrap();
        let weights =
            to_weights(terl_wire::WeightsKind::Policy, 1, 0, sac.policy_tensors()).unwrap();
        let encoded = prost::Message::encoded_len(&terl_wire::pb::WeightsUpdate::from(&weights));
        let mut cfg = terl_runtime::RunConfig::load(&path).unwrap();
        cfg.sac = sac_config;
        let bound = cfg.weight_message_bytes(10)[0].1;
        assert!(
            encoded as u64 <= bound && bound < encoded as u64 + 2048,
            "encoded {encoded}, bound {bound}"
        );
    }
}
