//! Checkpointing: periodic checkpoints every `[cluster] checkpoint_every_secs` (the newest
//! `keep_checkpoints` kept), checkpoints `SaveCheckpoint` asks for, and the final one; a failed
//! periodic write stops the learner or is counted and logged, as `[cluster]
//! on_checkpoint_error` says.

use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use terl_runtime::{ClusterConfig, OnCheckpointError};
use terl_wire::{CheckpointRequest, CheckpointSaved};

use crate::checkpoint::{CheckpointWriter, Snapshot};

/// A `SaveCheckpoint` request handed to the trainer thread, with where to send the answer.
#[derive(Debug)]
pub struct CheckpointJob {
    /// The request (an optional label for the checkpoint's file name).
    pub request: CheckpointRequest,
    /// Where the trainer sends the saved checkpoint, or the error in words.
    pub reply: tokio::sync::oneshot::Sender<Result<CheckpointSaved, String>>,
}

/// The planner's file for tools (`planner.safetensors`): tensors and metadata.
pub(crate) type ToolFile = (
    Vec<terl_nn::tensors::Tensor>,
    std::collections::BTreeMap<String, String>,
);

/// The learner's checkpoint schedule and its failures.
pub(crate) struct CheckpointSchedule {
    writer: CheckpointWriter,
    every: Option<Duration>,
    last: Instant,
    on_error: OnCheckpointError,
    /// Periodic checkpoints that could not be written (status: `checkpoint_failures`).
    pub(crate) failures: u64,
}

impl CheckpointSchedule {
    /// Opens (creates) `dir` with the schedule of `cluster`; the first periodic checkpoint is
    /// due `checkpoint_every_secs` from now.
    ///
    /// # Errors
    /// `dir` cannot be created or read.
    pub(crate) fn open(dir: PathBuf, cluster: &ClusterConfig) -> anyhow::Result<Self> {
        Ok(Self {
            writer: CheckpointWriter::open(dir, cluster.keep_checkpoints)?,
            every: (cluster.checkpoint_every_secs > 0.0)
                .then(|| Duration::from_secs_f64(cluster.checkpoint_every_secs)),
            last: Instant::now(),
            on_error: cluster.on_checkpoint_error,
            failures: 0,
        })
    }

    /// Answers every pending `SaveCheckpoint` request with a checkpoint named
    /// `<label or "requested">-update-<updates>` (or the error, as text).
    pub(crate) fn answer_requests(
        &self,
        jobs: &mpsc::Receiver<CheckpointJob>,
        updates: u64,
        policy_version: u64,
        snapshot: impl Fn() -> anyhow::Result<Snapshot>,
    ) {
        while let Ok(job) = jobs.try_recv() {
            let name = match &job.request.label {
                Some(label) => format!("{label}-update-{updates:010}"),
                None => format!("requested-update-{updates:010}"),
            };
            let answer = snapshot()
                .and_then(|snapshot| self.writer.write(&name, &snapshot))
                .map(|path| CheckpointSaved {
                    path: path.display().to_string(),
                    learner_update: updates,
                    policy_version,
                })
                .map_err(|e| format!("{e:#}"));
            let _ = job.reply.send(answer);
        }
    }

    /// Writes the periodic checkpoint `update-<updates>` (and the planner's tool file) when
    /// one is due. A failed write is counted and logged; with `on_checkpoint_error = "stop"`
    /// it is also returned, which stops the learner.
    ///
    /// # Errors
    /// A failed write under `on_checkpoint_error = "stop"`.
    pub(crate) fn periodic(
        &mut self,
        updates: u64,
        snapshot: impl FnOnce() -> anyhow::Result<Snapshot>,
        tool_file: impl FnOnce() -> anyhow::Result<Option<ToolFile>>,
    ) -> anyhow::Result<()> {
        if self.every.is_none_or(|every| self.last.elapsed() < every) {
            return Ok(());
        }
        self.last = Instant::now();
        let written = snapshot()
            .and_then(|snapshot| self.writer.write_periodic(updates, &snapshot))
            .and_then(|path| {
                if let Some((tensors, meta)) = tool_file()? {
                    self.writer.planner(tensors, &meta)?;
                }
                Ok(path)
            });
        match written {
            Ok(path) => {
                tracing::info!(path = %path.display(), updates, "checkpoint");
                Ok(())
            }
            Err(e) => {
                self.failures += 1;
                tracing::error!(failures = self.failures, "{e:#}");
                if self.on_error == OnCheckpointError::Stop {
                    return Err(e).context(
                        "stopping: a checkpoint could not be written \
                         (cluster.on_checkpoint_error = \"stop\"; \"continue\" keeps training)",
                    );
                }
                Ok(())
            }
        }
    }

    /// Writes the final checkpoint (and the planner's tool file); its path.
    ///
    /// # Errors
    /// The write failed.
    pub(crate) fn last(
        &self,
        snapshot: &Snapshot,
        tool_file: Option<ToolFile>,
    ) -> anyhow::Result<PathBuf> {
        let path = self.writer.write("final", snapshot)?;
        if let Some((tensors, meta)) = tool_file {
            self.writer.planner(tensors, &meta)?;
        }
        Ok(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cluster(on_error: OnCheckpointError, keep: usize) -> ClusterConfig {
        ClusterConfig {
            checkpoint_every_secs: 1e-9,
            keep_checkpoints: keep,
            on_checkpoint_error: on_error,
            ..ClusterConfig::default()
        }
    }

    fn snapshot() -> anyhow::Result<Snapshot> {
        let sac = terl_rl::Sac::<f32>::new(terl_rl::SacConfig {
            num_tasks: 1,
            policy_hidden: vec![4],
            critic_hidden: vec![4],
            ..terl_rl::SacConfig::default()
        })?;
        Ok(Snapshot {
            tensors: sac.policy_tensors(),
            metadata: Default::default(),
        })
    }

    fn periodic_files(dir: &std::path::Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with("update-"))
            .collect();
        names.sort();
        names
    }

    /// Only the newest `keep_checkpoints` periodic checkpoints stay; the final one is apart.
    #[test]
    fn the_newest_keep_checkpoints_are_kept() {
        let dir = tempfile::tempdir().unwrap();
        let ckpt = dir.path().join("checkpoints");
        let mut c =
            CheckpointSchedule::open(ckpt.clone(), &cluster(OnCheckpointError::Stop, 2)).unwrap();
        for updates in [10, 20, 30, 40] {
            std::thread::sleep(Duration::from_millis(2));
            c.periodic(updates, snapshot, || Ok(None)).unwrap();
        }
        assert_eq!(
            periodic_files(&ckpt),
            [
                "update-0000000030.safetensors",
                "update-0000000040.safetensors"
            ]
        );
        c.last(&snapshot().unwrap(), None).unwrap();
        assert!(ckpt.join("final.safetensors").exists());
        assert_eq!(c.failures, 0);
    }

    /// A write into a checkpoint folder that has become a file fails (also as root): counted
    /// and returned under "stop", counted only under "continue".
    #[test]
    fn a_failed_write_stops_or_is_counted_as_configured() {
        for on_error in [OnCheckpointError::Stop, OnCheckpointError::Continue] {
            let dir = tempfile::tempdir().unwrap();
            let ckpt = dir.path().join("checkpoints");
            let mut c = CheckpointSchedule::open(ckpt.clone(), &cluster(on_error, 3)).unwrap();
            std::fs::remove_dir(&ckpt).unwrap();
            std::fs::write(&ckpt, "not a folder").unwrap();
            std::thread::sleep(Duration::from_millis(2));
            let result = c.periodic(10, snapshot, || Ok(None));
            assert_eq!(c.failures, 1);
            match on_error {
                OnCheckpointError::Stop => {
                    let e = format!("{:#}", result.unwrap_err());
                    assert!(
                        e.contains("stopping: a checkpoint could not be written"),
                        "{e}"
                    );
                    assert!(e.contains("update-0000000010"), "{e}");
                }
                OnCheckpointError::Continue => result.unwrap(),
            }
        }
    }
}
