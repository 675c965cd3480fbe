//! The learner's checkpoints: what one holds, how it is written, and which one a resumed run
//! continues from.
//!
//! **One file holds everything a run needs to continue** (`checkpoints/<name>.safetensors`):
//! the SAC state of [`Sac::checkpoint_tensors`] (policy, both critics and their targets, every
//! Adam state, per-task `log α` and its optimiser, the update counter, the noise generator),
//! with `algorithm = "terl"` the planner's ([`terl_rl::Tep::checkpoint_tensors`]: F, AN, both
//! targets, both optimisers, counters), and the learner's own counters as JSON under
//! [`LEARNER_STATE_KEY`] ([`LearnerState`]: env steps, published versions, success windows, the
//! replay sampler's generator, the planner's sampler and interleaving offset). The policy
//! tensors keep the names `terl eval` reads, so any learner checkpoint can be evaluated.
//! `planner.safetensors` (F, AN and targets) is still written next to them for tools.
//!
//! **Writing** goes through [`terl_nn::tensors::save_file`]: temporary file, `fsync`, rename,
//! `fsync` of the folder, with a format version and a content checksum in the metadata.
//! Periodic checkpoints (`update-<updates>.safetensors`) are pruned to `keep_checkpoints`,
//! counting the files earlier processes of the same run folder left.
//!
//! **Resuming** ([`newest_intact`]) reads every checkpoint of the folder, verifies its checksum
//! and shapes, skips damaged ones with a warning naming the file and the reason, and continues
//! from the one with the most updates. The replay buffer is **not** persisted (MT10's is 10 ×
//! 100k transitions, ~340 MB, and grows with `replay_capacity_per_task`): after a resume the learner
//! refills it with `train.warmup_env_steps` fresh transitions from the restored policy before
//! updates continue, at the run's update-to-data ratio from then on.

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};
use terl_nn::tensors::{save_file, Tensor, TensorFile};
use terl_rl::Sac;

/// Metadata key of the learner's own state ([`LearnerState`] as JSON).
pub(crate) const LEARNER_STATE_KEY: &str = "terl.learner_state";

/// A generator state: the ChaCha seed (hex) and word position.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct RngState {
    pub(crate) seed: String,
    pub(crate) word_pos: String,
}

impl RngState {
    pub(crate) fn of(rng: &rand_chacha::ChaCha8Rng) -> Self {
        Self {
            seed: rng.get_seed().iter().map(|b| format!("{b:02x}")).collect(),
            word_pos: rng.get_word_pos().to_string(),
        }
    }

    pub(crate) fn restore(&self) -> anyhow::Result<rand_chacha::ChaCha8Rng> {
        use rand::SeedableRng;
        anyhow::ensure!(
            self.seed.len() == 64 && self.seed.is_ascii(),
            "bad generator seed in the checkpoint"
        );
        let mut seed = [0u8; 32];
        for (i, b) in seed.iter_mut().enumerate() {
            *b = u8::from_str_radix(&self.seed[2 * i..2 * i + 2], 16)
                .context("bad generator seed in the checkpoint")?;
        }
        let pos: u128 = self
            .word_pos
            .parse()
            .context("bad generator position in the checkpoint")?;
        let mut rng = rand_chacha::ChaCha8Rng::from_seed(seed);
        rng.set_word_pos(pos);
        Ok(rng)
    }
}

/// The planner trainer's state beyond its networks.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct PlannerState {
    pub(crate) sac_offset: Option<u64>,
    pub(crate) selected: u64,
    pub(crate) rejected: u64,
    pub(crate) failed_updates: u64,
    pub(crate) published_version: u64,
    pub(crate) rng: RngState,
}

/// The learner's counters and generators that a resumed run continues from.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct LearnerState {
    /// The run's task names in task-id order (a resume with another task list is refused).
    pub(crate) tasks: Vec<String>,
    pub(crate) algorithm: String,
    pub(crate) env_steps: u64,
    pub(crate) policy_version: u64,
    pub(crate) critic_version: u64,
    pub(crate) selected_samples: u64,
    pub(crate) guided_steps: u64,
    pub(crate) failed_updates: u64,
    pub(crate) rejected_batches: u64,
    /// Per task, the training-episode success window, oldest first (`'1'` success).
    pub(crate) success_windows: Vec<String>,
    /// The replay sampler's generator.
    pub(crate) sampler: RngState,
    pub(crate) planner: Option<PlannerState>,
    /// Set in the final checkpoint of a finished run: why it ended (`budget`: the env-step
    /// budget; `planner_ready`: stage 1's `cluster.stop_at_planner_samples_per_task`). Absent
    /// in checkpoints of runs still going (and in those written before the field existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) finished: Option<String>,
}

/// A learner checkpoint about to be written or just read.
pub(crate) struct Snapshot {
    pub(crate) tensors: Vec<Tensor>,
    pub(crate) metadata: BTreeMap<String, String>,
}

impl Snapshot {
    /// SAC state, optional planner tensors and the learner state.
    pub(crate) fn new(
        sac: &Sac<f32>,
        planner: Option<Vec<Tensor>>,
        state: &LearnerState,
    ) -> anyhow::Result<Self> {
        let (mut tensors, mut metadata) = sac.checkpoint_tensors();
        tensors.extend(planner.into_iter().flatten());
        metadata.insert(LEARNER_STATE_KEY.into(), serde_json::to_string(state)?);
        Ok(Self { tensors, metadata })
    }
}

/// A checkpoint found intact in a run folder.
pub(crate) struct Found {
    pub(crate) path: PathBuf,
    pub(crate) file: TensorFile,
    pub(crate) state: LearnerState,
    pub(crate) updates: u64,
}

/// Writes the learner's checkpoints into one folder and prunes the periodic ones.
pub(crate) struct CheckpointWriter {
    dir: PathBuf,
    keep: usize,
    /// Periodic checkpoints in the folder, oldest first (including earlier processes' files).
    periodic: VecDeque<PathBuf>,
}

/// `update-<10 digits>.safetensors`: a periodic checkpoint's name.
fn is_periodic(name: &str) -> bool {
    name.strip_prefix("update-")
        .and_then(|r| r.strip_suffix(".safetensors"))
        .is_some_and(|d| d.len() == 10 && d.bytes().all(|b| b.is_ascii_digit()))
}

impl CheckpointWriter {
    /// Opens (creates) `dir`, removes temporary files a killed writer left, and adopts the
    /// periodic checkpoints already there so `keep` counts them.
    pub(crate) fn open(dir: PathBuf, keep: usize) -> anyhow::Result<Self> {
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let mut periodic = Vec::new();
        for entry in
            std::fs::read_dir(&dir).with_context(|| format!("reading {}", dir.display()))?
        {
            let entry = entry?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.ends_with(".tmp") {
                tracing::info!(file = %entry.path().display(), "removing a checkpoint a killed writer left unfinished");
                let _ = std::fs::remove_file(entry.path());
            } else if is_periodic(&name) {
                periodic.push(entry.path());
            }
        }
        periodic.sort();
        Ok(Self {
            dir,
            keep: keep.max(1),
            periodic: periodic.into(),
        })
    }

    /// Writes `<name>.safetensors`.
    pub(crate) fn write(&self, name: &str, snapshot: &Snapshot) -> anyhow::Result<PathBuf> {
        let path = self.dir.join(format!("{name}.safetensors"));
        save_file(&path, &snapshot.tensors, &snapshot.metadata)
            .with_context(|| format!("cannot write the checkpoint {}", path.display()))?;
        Ok(path)
    }

    /// Writes `planner.safetensors` (F, AN and targets, for tools; resuming reads the planner
    /// from the learner checkpoint).
    pub(crate) fn planner(
        &self,
        tensors: Vec<Tensor>,
        metadata: &BTreeMap<String, String>,
    ) -> anyhow::Result<()> {
        let path = self.dir.join("planner.safetensors");
        save_file(&path, &tensors, metadata)
            .with_context(|| format!("cannot write {}", path.display()))
    }

    /// Writes `update-<updates>.safetensors` and deletes the oldest periodic checkpoints
    /// beyond `keep`.
    pub(crate) fn write_periodic(
        &mut self,
        updates: u64,
        snapshot: &Snapshot,
    ) -> anyhow::Result<PathBuf> {
        let path = self.write(&format!("update-{updates:010}"), snapshot)?;
        if !self.periodic.contains(&path) {
            self.periodic.push_back(path.clone());
        }
        while self.periodic.len() > self.keep {
            if let Some(old) = self.periodic.pop_front() {
                let _ = std::fs::remove_file(old);
            }
        }
        Ok(path)
    }
}

/// Reads one checkpoint and its learner state.
fn read(path: &Path) -> anyhow::Result<Found> {
    let file = TensorFile::load(path)?;
    let state: LearnerState = serde_json::from_str(
        file.metadata
            .get(LEARNER_STATE_KEY)
            .context("no learner state in it (not a checkpoint of a cluster learner)")?,
    )
    .context("its learner state does not parse")?;
    let updates = file.i64_values("counters", &[2])?[0].max(0) as u64;
    Ok(Found {
        path: path.to_path_buf(),
        file,
        state,
        updates,
    })
}

/// The intact learner checkpoint with the most updates in `dir` (ties: the most env steps,
/// then the newest file), or
/// `None` if the folder holds no checkpoint at all. Damaged files (bad checksum, cut short,
/// not a learner checkpoint) are skipped with a warning each.
///
/// # Errors
/// CheckpointSchedule exist but none is intact (resuming would silently lose the run), or the folder
/// cannot be read.
pub(crate) fn newest_intact(dir: &Path) -> anyhow::Result<Option<Found>> {
    let mut candidates = Vec::new();
    match std::fs::read_dir(dir) {
        Ok(entries) => {
            for entry in entries {
                let path = entry?.path();
                let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
                if name
                    .as_deref()
                    .is_some_and(|n| n.ends_with(".safetensors") && n != "planner.safetensors")
                {
                    candidates.push(path);
                }
            }
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e).with_context(|| format!("reading {}", dir.display())),
    }
    if candidates.is_empty() {
        return Ok(None);
    }
    let mut best: Option<(Found, std::time::SystemTime)> = None;
    let mut damaged = Vec::new();
    for path in candidates {
        match read(&path) {
            Ok(found) => {
                let mtime = std::fs::metadata(&path)
                    .and_then(|m| m.modified())
                    .unwrap_or(std::time::UNIX_EPOCH);
                let key = (found.updates, found.state.env_steps, mtime);
                let better = best
                    .as_ref()
                    .is_none_or(|(b, t)| key > (b.updates, b.state.env_steps, *t));
                if better {
                    best = Some((found, mtime));
                }
            }
            Err(e) => {
                tracing::warn!(file = %path.display(), "checkpoint is damaged or unusable, skipped: {e:#}");
                damaged.push(format!("{} ({e:#})", path.display()));
            }
        }
    }
    match best {
        Some((found, _)) => Ok(Some(found)),
        None => anyhow::bail!(
            "no intact checkpoint in {} to resume from: {}",
            dir.display(),
            damaged.join("; ")
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_rl::SacConfig;

    fn sac(seed: u64) -> Sac<f32> {
        Sac::new(SacConfig {
            obs_dim: 5,
            act_dim: 2,
            num_tasks: 2,
            policy_hidden: vec![8],
            critic_hidden: vec![8],
            batch_size: 4,
            seed,
            ..SacConfig::default()
        })
        .unwrap()
    }

    fn state(env_steps: u64) -> LearnerState {
        LearnerState {
            tasks: vec!["reach-v3".into(), "push-v3".into()],
            env_steps,
            success_windows: vec!["101".into(), String::new()],
            ..LearnerState::default()
        }
    }

    /// Why a run finished survives its final checkpoint (what `--resume` reads to stay
    /// finished); a state written without the field reads as "not finished".
    #[test]
    fn the_reason_a_run_finished_is_kept_in_its_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let ckpt = dir.path().join("checkpoints");
        let s = sac(1);
        let mut finished = state(50);
        finished.finished = Some("planner_ready".into());
        CheckpointWriter::open(ckpt.clone(), 2)
            .unwrap()
            .write_periodic(5, &Snapshot::new(&s, None, &finished).unwrap())
            .unwrap();
        let found = newest_intact(&ckpt).unwrap().unwrap();
        assert_eq!(found.state.finished.as_deref(), Some("planner_ready"));
        let mut json = serde_json::to_value(state(50)).unwrap();
        assert!(json.get("finished").is_none());
        json.as_object_mut().unwrap().remove("finished");
        let old: LearnerState = serde_json::from_value(json).unwrap();
        assert_eq!(old.finished, None);
    }

    /// The newest intact checkpoint wins; a damaged newest one is skipped for the previous;
    /// `keep` counts files an earlier process left; unfinished temporary files are removed.
    #[test]
    fn resume_skips_damaged_checkpoints_and_keep_spans_processes() {
        let dir = tempfile::tempdir().unwrap();
        let ckpt = dir.path().join("checkpoints");
        assert!(newest_intact(&ckpt).unwrap().is_none());
        let s = sac(1);
        {
            let mut c = CheckpointWriter::open(ckpt.clone(), 2).unwrap();
            for (u, steps) in [(10, 100), (20, 200)] {
                c.write_periodic(u, &Snapshot::new(&s, None, &state(steps)).unwrap())
                    .unwrap();
            }
        }
        std::fs::write(ckpt.join("update-0000000025.safetensors.tmp"), b"half").unwrap();
        // A second process adopts both files: one more write prunes the oldest.
        let mut c = CheckpointWriter::open(ckpt.clone(), 2).unwrap();
        assert!(!ckpt.join("update-0000000025.safetensors.tmp").exists());
        c.write_periodic(30, &Snapshot::new(&s, None, &state(300)).unwrap())
            .unwrap();
        let mut names: Vec<String> = std::fs::read_dir(&ckpt)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "update-0000000020.safetensors",
                "update-0000000030.safetensors"
            ]
        );
        // No update ran (update counters 0): the env-step counter ranks them.
        let found = newest_intact(&ckpt).unwrap().unwrap();
        assert_eq!(found.state.env_steps, 300);

        // Damage the newest: the previous one is used.
        let newest = ckpt.join("update-0000000030.safetensors");
        let mut bytes = std::fs::read(&newest).unwrap();
        let n = bytes.len();
        bytes[n - 3] ^= 0x10;
        std::fs::write(&newest, &bytes).unwrap();
        let found = newest_intact(&ckpt).unwrap().unwrap();
        assert_eq!(found.state.env_steps, 200);
        assert_eq!(found.state, state(200));

        // Cut the other short too: nothing intact is an error naming both files.
        let other = ckpt.join("update-0000000020.safetensors");
        let bytes = std::fs::read(&other).unwrap();
        std::fs::write(&other, &bytes[..bytes.len() / 2]).unwrap();
        let err = newest_intact(&ckpt).err().unwrap().to_string();
        assert!(
            err.contains("update-0000000030") && err.contains("update-0000000020"),
            "{err}"
        );
    }

    /// A full disk (a 512 KiB tmpfs): the write fails with an error naming the file, leaves no
    /// temporary file and no file under the checkpoint's name, and the earlier checkpoint stays
    /// intact and is what a resume finds. Needs root to mount; elsewhere it says so and skips.
    #[test]
    fn a_full_disk_fails_the_write_cleanly_and_keeps_the_earlier_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let mount = dir.path().join("small");
        std::fs::create_dir_all(&mount).unwrap();
        let mounted = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=512k", "tmpfs"])
            .arg(&mount)
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        // The full-disk case needs a small filesystem of its own: a test that cannot make one
        // fails rather than passing without exercising it (the suite runs as root, CI too).
        assert!(
            mounted,
            "cannot mount a tmpfs at {} (needs root, as ./deploy/test.sh and CI run)",
            mount.display()
        );
        struct Unmount(PathBuf);
        impl Drop for Unmount {
            fn drop(&mut self) {
                let _ = std::process::Command::new("umount").arg(&self.0).status();
            }
        }
        let _guard = Unmount(mount.clone());
        let ckpt = mount.join("checkpoints");
        let mut c = CheckpointWriter::open(ckpt.clone(), 3).unwrap();
        let small = sac(1);
        c.write_periodic(1, &Snapshot::new(&small, None, &state(10)).unwrap())
            .unwrap();
        // ~600k parameters with targets and Adam moments: far more than what is left.
        let big = Sac::<f32>::new(SacConfig {
            obs_dim: 5,
            act_dim: 2,
            num_tasks: 2,
            policy_hidden: vec![256, 256],
            critic_hidden: vec![256, 256],
            batch_size: 4,
            ..SacConfig::default()
        })
        .unwrap();
        let err = c
            .write_periodic(2, &Snapshot::new(&big, None, &state(20)).unwrap())
            .unwrap_err();
        let msg = format!("{err:#}");
        assert!(msg.contains("update-0000000002"), "{msg}");
        let names: Vec<String> = std::fs::read_dir(&ckpt)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["update-0000000001.safetensors"], "{msg}");
        let found = newest_intact(&ckpt).unwrap().unwrap();
        assert_eq!(found.state.env_steps, 10);
    }

    #[test]
    fn generator_states_round_trip() {
        use rand::{Rng, SeedableRng};
        let mut a = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let _: u64 = a.gen();
        let mut b = RngState::of(&a).restore().unwrap();
        assert_eq!(a.gen::<u64>(), b.gen::<u64>());
        assert!(RngState::default().restore().is_err());
    }
}
