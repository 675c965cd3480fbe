//! The training loop of the learner process (its own thread): a short loop over the learner's
//! parts.
//!
//! One round: [`Staging`] drains transition batches from the transport and loads them into
//! replay while the rate limiter allows inserts (when it does not, batches stay queued and
//! actors meet back-pressure); finished episodes (success windows) and selected samples are
//! drained; updates run while the limiter allows samples; the [`Publisher`] publishes weights
//! every `publish_every_updates`; [`CheckpointSchedule`] answers checkpoint requests and writes the
//! periodic checkpoint when due; the [`StatusBoard`] refreshes the status snapshot. Policy
//! versions are the learner's update count at publication, so a transition's staleness is
//! "updates behind" directly.

use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_rl::replay::MultiTaskReplay;
use terl_rl::{Batch, Sac, SacError, SuccessWindow};
use terl_runtime::{Algorithm, Lockstep};
use terl_transport::{
    EpisodeSummary, Message, MessageSource, RateLimiter, SelectedBatch, TransitionBatch, Transport,
    ACTION_DIM, OBS_DIM, TRANSITIONS_PER_BATCH,
};
use terl_wire::WeightHub;

use crate::checkpoint::{self, LearnerState, RngState, Snapshot};
use crate::checkpointing::{CheckpointJob, CheckpointSchedule};
use crate::lockstep::LockstepStaging;
use crate::metrics::MetricsLog;
use crate::planner::PlannerTrainer;
use crate::publisher::Publisher;
use crate::staging::Staging;
use crate::status::{Counters, Shown, Sources, StatusBoard};
use crate::{LearnerConfig, Shared};

/// Updates per round at most, so queued batches are drained regularly.
const MAX_UPDATES_PER_ROUND: usize = 16;

/// The newest intact checkpoint to continue from with `--resume` (`None` without it, or when
/// the run has none yet: it then starts fresh, with a warning).
fn resume_point(
    config: &LearnerConfig,
    checkpoint_dir: &std::path::Path,
) -> anyhow::Result<Option<checkpoint::Found>> {
    if !config.resume {
        return Ok(None);
    }
    let found = checkpoint::newest_intact(checkpoint_dir)?;
    if found.is_none() {
        tracing::warn!(dir = %checkpoint_dir.display(), "--resume: the run has no checkpoint yet; starting fresh");
    }
    Ok(found)
}

/// The TEP planner with its buffer loaded from `--tep-dataset` files and, when resuming, from
/// the run's own dataset files (the TEP buffer is not in the checkpoint: the run's dataset
/// holds every selected sample it received, one file per selector start).
fn open_planner(
    config: &LearnerConfig,
    tasks: &[&str],
    resuming: bool,
) -> anyhow::Result<PlannerTrainer> {
    let run = &config.run;
    let mut p = PlannerTrainer::new(
        run.tep.clone(),
        run.guidance.clone(),
        tasks.len(),
        run.train.seed,
    )?;
    let mut datasets = config.tep_datasets.clone();
    if resuming {
        datasets.extend(terl_telemetry::existing_paths(
            &config.run_dir,
            "tep-dataset",
        ));
    }
    crate::dataset::load_all(&datasets, tasks, &mut p)?;
    // A planner trained offline is checked on the held-out trajectories of the datasets at once,
    // so the tasks it passes are guided from the first step.
    p.check(true);
    Ok(p)
}

/// One SAC update on a fresh batch from replay. A batch with non-finite values is skipped;
/// non-finite losses or gradients are counted, and `max_failed_in_a_row` of them in a row stop
/// the learner.
fn update_once(
    sac: &mut Sac<f32>,
    replay: &mut MultiTaskReplay,
    rng: &mut ChaCha8Rng,
    batch: &mut Batch,
    metrics: &mut MetricsLog,
    c: &mut Counters,
    max_failed_in_a_row: u64,
) -> anyhow::Result<()> {
    replay.sample_into(sac.config().batch_size, rng, batch);
    let began = Instant::now();
    let result = sac.update(batch);
    c.update_time += began.elapsed();
    match result {
        Ok(stats) => {
            c.failed_in_a_row = 0;
            metrics.record_update(&stats);
        }
        Err(SacError::NonFiniteBatch { .. }) => {}
        Err(e @ (SacError::NonFiniteLoss { .. } | SacError::NonFiniteGradient { .. })) => {
            c.failed_updates += 1;
            c.failed_in_a_row += 1;
            if c.failed_in_a_row >= max_failed_in_a_row {
                return Err(e).context("too many failed updates in a row");
            }
        }
        Err(e) => return Err(e.into()),
    }
    Ok(())
}

/// The learner's mutable parts one update needs.
struct Learning<'a> {
    sac: &'a mut Sac<f32>,
    replay: &'a mut MultiTaskReplay,
    rng: &'a mut ChaCha8Rng,
    batch: &'a mut Batch,
    metrics: &'a mut MetricsLog,
    c: &'a mut Counters,
    max_failed_in_a_row: u64,
}

impl Learning<'_> {
    fn update(&mut self) -> anyhow::Result<()> {
        update_once(
            self.sac,
            self.replay,
            self.rng,
            self.batch,
            self.metrics,
            self.c,
            self.max_failed_in_a_row,
        )
    }

    /// Up to [`MAX_UPDATES_PER_ROUND`] updates while the rate limiter allows; true if any ran.
    fn rate_limited(&mut self, limiter: &mut RateLimiter) -> anyhow::Result<bool> {
        let mut ran = false;
        for _ in 0..MAX_UPDATES_PER_ROUND {
            if !limiter.can_sample(1) {
                break;
            }
            limiter.record_sample(1);
            ran = true;
            self.update()?;
        }
        Ok(ran)
    }

    /// Up to [`MAX_UPDATES_PER_ROUND`] of the updates the reproducible schedule has due; true if
    /// any ran.
    fn scheduled(&mut self, lockstep: &mut LockstepStaging) -> anyhow::Result<bool> {
        let n = lockstep.updates_due().min(MAX_UPDATES_PER_ROUND as u64);
        for _ in 0..n {
            self.update()?;
            lockstep.record_updates(1);
        }
        Ok(n > 0)
    }
}

/// The SAC configuration of this run: the run file's `[sac]` with Meta-World's dimensions and
/// the run's task count.
pub(crate) fn sac_config(config: &LearnerConfig) -> anyhow::Result<terl_rl::SacConfig> {
    let tasks = terl_runtime::resolve_tasks(&config.run.tasks)?;
    Ok(config.run.sac_config(tasks.len()))
}

/// The learner's standalone update rate ([`terl_rl::sac::standalone_update_rate`]) over
/// `cluster.learner_calibrate_secs`, logged; 0 when that is 0. The learner calls it before it
/// announces its address, so under the launcher nothing else of the cluster runs yet (a
/// restarted learner is timed beside the running actors).
pub(crate) fn calibrate(config: &LearnerConfig) -> anyhow::Result<f64> {
    let seconds = config.run.cluster.learner_calibrate_secs;
    if seconds <= 0.0 {
        return Ok(0.0);
    }
    let sac_config = sac_config(config)?;
    tracing::info!(
        seconds,
        "timing the standalone update rate before serving (cluster.learner_calibrate_secs)"
    );
    let rate = terl_rl::sac::standalone_update_rate(&sac_config, seconds)
        .context("timing the learner's standalone update rate")?;
    tracing::info!(
        updates_per_second = format!("{rate:.1}"),
        batch = sac_config.batch_size,
        threads = sac_config.threads,
        "standalone update rate (cluster.learner_calibrate_secs)"
    );
    Ok(rate)
}

/// Runs the training loop on `transport`'s streams until `shared.stop` is set, the training
/// budget is reached or something fails; writes the final checkpoint on the way out. Sends on
/// `opened` once the streams are open and the networks built (or restored): the learner
/// announces its address only then, so a learner refused by the run's streams (another
/// learner of the run is live) never replaces the live one's address file.
pub(crate) fn run<T: Transport>(
    config: &LearnerConfig,
    transport: &T,
    shared: &Shared,
    hub: &WeightHub,
    checkpoint_jobs: &mpsc::Receiver<CheckpointJob>,
    opened: tokio::sync::oneshot::Sender<()>,
) -> anyhow::Result<()> {
    let mut trainer = Trainer::open(config, transport, shared, hub)?;
    // The receiver is gone only when the service is already stopping.
    let _ = opened.send(());
    while !shared.stop.load(Ordering::Relaxed) && !trainer.finished() {
        if !trainer.round(hub, checkpoint_jobs, shared)? {
            std::thread::sleep(Duration::from_micros(500));
        }
    }
    trainer.finish(shared)
}

/// What a checkpoint holds: the networks, the planner, the sampler and the counters.
struct Model {
    tasks: Vec<&'static str>,
    algorithm: Algorithm,
    sac: Sac<f32>,
    planner: Option<PlannerTrainer>,
    rng: ChaCha8Rng,
    publisher: Publisher,
    c: Counters,
    /// Why the run is finished (`budget`, `planner_ready`) once it is; written into the final
    /// checkpoint so a resumed learner knows.
    finished: Option<&'static str>,
}

impl Model {
    /// The learner checkpoint of this moment.
    fn snapshot(&self) -> anyhow::Result<Snapshot> {
        let state = learner_state(
            &self.tasks,
            self.algorithm,
            &self.c,
            &self.publisher,
            &self.rng,
            self.planner.as_ref(),
            self.finished,
        );
        Snapshot::new(
            &self.sac,
            self.planner
                .as_ref()
                .map(PlannerTrainer::checkpoint_tensors),
            &state,
        )
    }

    /// The planner's tool file (for `terl planner eval` and the actors), with TERL.
    fn tool_file(&self) -> anyhow::Result<Option<crate::checkpointing::ToolFile>> {
        self.planner
            .as_ref()
            .map(PlannerTrainer::tool_file)
            .transpose()
    }
}

/// Where transitions, episodes and selected samples come in.
struct Inbound {
    transitions: Box<dyn MessageSource<TransitionBatch>>,
    staging: Staging,
    limiter: RateLimiter,
    /// The reproducible schedule (`cluster.reproducible`), instead of the rate limiter.
    lockstep: Option<LockstepStaging>,
    episodes: Box<dyn MessageSource<EpisodeSummary>>,
    episode: Box<EpisodeSummary>,
    selected: Box<dyn MessageSource<SelectedBatch>>,
    selected_batch: Box<SelectedBatch>,
}

/// The learner as a state: [`Trainer::open`] builds (or resumes) it, [`Trainer::round`] runs one
/// round of the loop, [`Trainer::finish`] writes the final checkpoint.
struct Trainer<'a> {
    config: &'a LearnerConfig,
    m: Model,
    inbound: Inbound,
    replay: MultiTaskReplay,
    batch: Batch,
    metrics: MetricsLog,
    checkpoints: CheckpointSchedule,
    board: StatusBoard,
}

impl<'a> Trainer<'a> {
    /// Opens the transport's streams, builds the networks and replay, and restores the newest
    /// checkpoint with `--resume` (publishing the restored networks at once).
    fn open<T: Transport>(
        config: &'a LearnerConfig,
        transport: &T,
        shared: &Shared,
        hub: &WeightHub,
    ) -> anyhow::Result<Self> {
        let run = &config.run;
        let tasks = terl_runtime::resolve_tasks(&run.tasks)?;
        let nt = tasks.len();
        let sac_config = sac_config(config)?;
        let terl = run.algorithm == Algorithm::Terl;
        let checkpoint_dir = config.run_dir.join("checkpoints");
        let resume_from = resume_point(config, &checkpoint_dir)?;
        anyhow::ensure!(
            !(run.cluster.reproducible && config.resume),
            "cluster.reproducible = true: a resumed run would not be the same run bit for bit \
             (the replay buffer is not in the checkpoint); start it again without --resume"
        );
        let planner = if terl {
            Some(open_planner(config, &tasks, resume_from.is_some())?)
        } else {
            None
        };
        let spi = run.samples_per_insert();
        let inbound = Inbound {
            transitions: transport.source::<TransitionBatch>().context(
                "cannot receive the run's transitions: a run has one learner, and another \
                 live learner of this run id may hold its streams (stop it, or use another \
                 --run-id)",
            )?,
            staging: Staging::new(config.num_actors * run.cluster.buffer_batches),
            limiter: RateLimiter::new(
                spi,
                run.train.warmup_env_steps,
                run.rate_error_buffer(TRANSITIONS_PER_BATCH),
            )?,
            lockstep: run
                .cluster
                .reproducible
                .then(|| LockstepStaging::new(Lockstep::new(run, config.num_actors))),
            episodes: transport.source::<EpisodeSummary>()?,
            episode: EpisodeSummary::empty(),
            selected: transport.source::<SelectedBatch>()?,
            selected_batch: SelectedBatch::empty(),
        };
        let start = Instant::now();
        let mut c = Counters::new(nt, run.train.success_window, start);
        c.standalone_updates_per_second = shared.standalone_updates_per_second;
        let task_names: Vec<String> = tasks.iter().map(|t| t.to_string()).collect();
        let mut m = Model {
            tasks,
            algorithm: run.algorithm,
            sac: Sac::for_tasks(sac_config.clone(), &task_names)?,
            planner,
            rng: ChaCha8Rng::seed_from_u64(run.train.seed ^ 0x1ea7_7e55),
            publisher: Publisher::new(
                run.cluster.publish_every_updates,
                run.cluster.critic_publish_every_updates,
                terl,
            ),
            c,
            finished: None,
        };
        let trainer = Self {
            config,
            inbound,
            replay: MultiTaskReplay::new(
                nt,
                run.train.replay_capacity_per_task,
                OBS_DIM,
                ACTION_DIM,
            ),
            batch: Batch::with_capacity(sac_config.batch_size, OBS_DIM, ACTION_DIM),
            metrics: MetricsLog::create(&config.run_dir)?,
            checkpoints: CheckpointSchedule::open(checkpoint_dir, &run.cluster)?,
            board: StatusBoard::new(start),
            m: {
                if let Some(found) = resume_from {
                    check_compatible(&found, &m.tasks, run.algorithm)?;
                    restore(
                        found,
                        &mut m.sac,
                        m.planner.as_mut(),
                        &mut m.rng,
                        &mut m.c,
                        &mut m.publisher,
                    )?;
                    // Actors and the selector get the restored networks at once (updates only
                    // continue once the replay buffer holds `warmup_env_steps` fresh
                    // transitions).
                    m.publisher.publish_all(hub, &m.sac, m.planner.as_mut())?;
                }
                m
            },
        };
        tracing::info!(
            tasks = nt,
            samples_per_insert = spi,
            warmup = run.train.warmup_env_steps,
            publish_every = run.cluster.publish_every_updates,
            algorithm = run.algorithm.as_str(),
            "trainer started"
        );
        Ok(trainer)
    }

    /// True (and logged) when the run is done: its env-step budget is reached (between
    /// reproducible rounds), or stage 1 of the pipeline has the planner samples it wanted.
    fn finished(&mut self) -> bool {
        let run = &self.config.run;
        let m = &self.m;
        let between_rounds = self
            .inbound
            .lockstep
            .as_ref()
            .is_none_or(LockstepStaging::between_rounds);
        let budget = run.train.total_env_steps;
        if budget > 0 && m.c.env_steps >= budget && between_rounds {
            tracing::info!(
                env_steps = m.c.env_steps,
                updates = m.sac.updates(),
                "training budget reached (train.total_env_steps); stopping"
            );
            self.m.finished = Some("budget");
            return true;
        }
        let wanted = run.cluster.stop_at_planner_samples_per_task;
        if wanted > 0 && m.planner.as_ref().is_some_and(|p| p.ready(wanted)) {
            tracing::info!(
                env_steps = m.c.env_steps,
                updates = m.sac.updates(),
                samples_per_task = wanted,
                "planner ready: every task validated with its selected samples \
                 (cluster.stop_at_planner_samples_per_task); stopping"
            );
            self.m.finished = Some("planner_ready");
            return true;
        }
        false
    }

    /// One round of the loop: intake, updates, publication, checkpoints, status. True if
    /// anything happened (the caller sleeps briefly otherwise).
    fn round(
        &mut self,
        hub: &WeightHub,
        checkpoint_jobs: &mpsc::Receiver<CheckpointJob>,
        shared: &Shared,
    ) -> anyhow::Result<bool> {
        let mut busy = self.stage()?;
        busy |= self.drain_inbound()?;
        busy |= self.learn()?;
        self.publish(hub)?;
        self.checkpoint(checkpoint_jobs)?;
        self.show(shared)?;
        Ok(busy)
    }

    /// Refreshes the status snapshot and the metrics log when due.
    fn show(&mut self, shared: &Shared) -> anyhow::Result<()> {
        let m = &mut self.m;
        self.board.tick(
            Sources {
                run_id: &self.config.run_id,
                algorithm: m.algorithm,
                tasks: &m.tasks,
                sac: &m.sac,
                replay: &self.replay,
                capacity: self.config.run.train.replay_capacity_per_task,
                shown: Shown {
                    policy_version: m.publisher.policy_version,
                    checkpoint_failures: self.checkpoints.failures,
                },
            },
            &mut m.c,
            m.planner.as_mut(),
            &mut self.metrics,
            shared,
        )
    }

    /// Transition batches into replay: by the rate limiter, or round by round under the
    /// reproducible schedule.
    fn stage(&mut self) -> anyhow::Result<bool> {
        let began = Instant::now();
        let nt = self.m.tasks.len();
        let (m, inb, replay) = (&mut self.m, &mut self.inbound, &mut self.replay);
        let version = m.publisher.policy_version;
        let busy = match inb.lockstep.as_mut() {
            Some(l) => {
                let got = l.fill(inb.transitions.as_mut())?;
                got | l.load_round(&mut m.c, |b, c| {
                    crate::staging::ingest(b, nt, replay, c, version)
                })
            }
            None => inb.staging.round(
                inb.transitions.as_mut(),
                &mut inb.limiter,
                nt,
                replay,
                &mut m.c,
                version,
            )?,
        };
        m.c.staging_round(began.elapsed());
        Ok(busy)
    }

    /// Finished episodes (success windows) and PTR-selected samples (the planner's buffer).
    fn drain_inbound(&mut self) -> anyhow::Result<bool> {
        let (m, inb) = (&mut self.m, &mut self.inbound);
        let mut busy = false;
        while inb.episodes.try_receive_into(&mut inb.episode)? {
            let e = &*inb.episode;
            m.c.inbound.episode(e);
            // A reproducible run keeps its success windows from the transitions, in round order.
            if inb.lockstep.is_none() {
                m.c.episode(e.task as usize, e.succeeded());
            }
            busy = true;
        }
        while inb.selected.try_receive_into(&mut inb.selected_batch)? {
            let s = &*inb.selected_batch;
            m.c.inbound.selected(s);
            m.c.selected_samples += match m.planner.as_mut() {
                Some(p) => p.ingest_batch(s),
                None => s.as_slice().len() as u64,
            };
            busy = true;
        }
        Ok(busy)
    }

    /// The SAC updates that are due, then the planner's.
    fn learn(&mut self) -> anyhow::Result<bool> {
        let m = &mut self.m;
        let mut learning = Learning {
            sac: &mut m.sac,
            replay: &mut self.replay,
            rng: &mut m.rng,
            batch: &mut self.batch,
            metrics: &mut self.metrics,
            c: &mut m.c,
            max_failed_in_a_row: self.config.run.train.max_consecutive_failed_updates,
        };
        let mut busy = match self.inbound.lockstep.as_mut() {
            Some(l) => learning.scheduled(l)?,
            None => learning.rate_limited(&mut self.inbound.limiter)?,
        };
        if let Some(p) = m.planner.as_mut() {
            busy |= p.train(m.sac.updates())? > 0;
        }
        Ok(busy)
    }

    /// Publishes the weights that are due (under the reproducible schedule: makes the round's
    /// version and releases what every actor is ready for).
    fn publish(&mut self, hub: &WeightHub) -> anyhow::Result<()> {
        let m = &mut self.m;
        match self.inbound.lockstep.as_mut() {
            Some(l) => {
                let sac = &m.sac;
                let made = l.finish_round(|version| {
                    crate::to_weights(
                        terl_wire::WeightsKind::Policy,
                        version,
                        sac.updates(),
                        sac.policy_tensors(),
                    )
                })?;
                if let Some(version) = made {
                    // The newest version made (what a checkpoint records), released or not.
                    m.publisher.policy_version = version;
                }
                l.release(hub)?;
            }
            None => {
                m.publisher.publish_due(hub, &m.sac, m.planner.as_mut())?;
            }
        }
        Ok(())
    }

    /// Answers `SaveCheckpoint` requests and writes the periodic checkpoint when due.
    fn checkpoint(&mut self, jobs: &mpsc::Receiver<CheckpointJob>) -> anyhow::Result<()> {
        let m = &self.m;
        let updates = m.sac.updates();
        self.checkpoints
            .answer_requests(jobs, updates, m.publisher.policy_version, || m.snapshot());
        self.checkpoints
            .periodic(updates, || m.snapshot(), || m.tool_file())
    }

    /// Shows the final counters (status and metrics log), closes the metrics log and writes
    /// the final checkpoint.
    fn finish(mut self, shared: &Shared) -> anyhow::Result<()> {
        self.board.due_now();
        self.show(shared)?;
        self.metrics.finish()?;
        let m = &self.m;
        let path = self.checkpoints.last(&m.snapshot()?, m.tool_file()?)?;
        tracing::info!(path = %path.display(), updates = m.sac.updates(), env_steps = m.c.env_steps, selected_samples = m.c.selected_samples, "trainer stopped; final checkpoint written");
        Ok(())
    }
}

/// The learner's counters for a checkpoint.
fn learner_state(
    tasks: &[&str],
    algorithm: Algorithm,
    c: &Counters,
    publisher: &Publisher,
    rng: &ChaCha8Rng,
    planner: Option<&PlannerTrainer>,
    finished: Option<&str>,
) -> LearnerState {
    LearnerState {
        tasks: tasks.iter().map(|t| (*t).to_string()).collect(),
        algorithm: algorithm.as_str().to_string(),
        env_steps: c.env_steps,
        policy_version: publisher.policy_version,
        critic_version: publisher.critic_version,
        selected_samples: c.selected_samples,
        guided_steps: c.guided_steps,
        failed_updates: c.failed_updates,
        rejected_batches: c.rejected_batches,
        success_windows: c
            .windows
            .iter()
            .map(|w| w.iter().map(|s| if s { '1' } else { '0' }).collect())
            .collect(),
        sampler: RngState::of(rng),
        planner: planner.map(PlannerTrainer::state),
        finished: finished.map(str::to_string),
    }
}

/// Refuses a checkpoint of another task list or algorithm.
fn check_compatible(
    found: &checkpoint::Found,
    tasks: &[&str],
    algorithm: Algorithm,
) -> anyhow::Result<()> {
    let state = &found.state;
    let path = found.path.display().to_string();
    anyhow::ensure!(
        state
            .tasks
            .iter()
            .map(String::as_str)
            .eq(tasks.iter().copied()),
        "cannot resume from {path}: it was trained on the tasks {:?}, the run file names {:?}",
        state.tasks,
        tasks
    );
    anyhow::ensure!(
        state.algorithm == algorithm.as_str(),
        "cannot resume from {path}: it is a checkpoint of an algorithm = \"{}\" run, the run file says \"{}\"",
        state.algorithm,
        algorithm.as_str()
    );
    Ok(())
}

/// Restores a found checkpoint into the freshly built learner, or fails with nothing half
/// restored that matters (the process then exits).
fn restore(
    found: checkpoint::Found,
    sac: &mut Sac<f32>,
    planner: Option<&mut PlannerTrainer>,
    rng: &mut ChaCha8Rng,
    c: &mut Counters,
    publisher: &mut Publisher,
) -> anyhow::Result<()> {
    let window_len = c.window_len();
    let state = &found.state;
    let path = found.path.display().to_string();
    let sampler = state.sampler.restore()?;
    sac.restore_checkpoint(&found.file).with_context(|| {
        format!("cannot resume from {path}: it does not fit this run's [sac] networks")
    })?;
    if let Some(p) = planner {
        let ps = state
            .planner
            .as_ref()
            .with_context(|| format!("cannot resume from {path}: it holds no planner state"))?;
        p.restore(&found.file, ps)
            .with_context(|| format!("cannot resume from {path}"))?;
    }
    *rng = sampler;
    c.env_steps = state.env_steps;
    publisher.policy_version = state.policy_version;
    publisher.critic_version = state.critic_version;
    c.selected_samples = state.selected_samples;
    c.guided_steps = state.guided_steps;
    c.failed_updates = state.failed_updates;
    c.rejected_batches = state.rejected_batches;
    for (w, saved) in c.windows.iter_mut().zip(&state.success_windows) {
        // A window of another length in the run file keeps the newest episodes.
        *w = SuccessWindow::new(window_len);
        saved.chars().for_each(|ch| w.push(ch == '1'));
    }
    c.resumed = Some((found.path.clone(), found.updates));
    // The first rate window counts from the restored update count, not from zero.
    c.start_rates_at(found.updates);
    tracing::info!(
        checkpoint = %path,
        updates = found.updates,
        env_steps = state.env_steps,
        "resumed; the replay buffer refills with warmup_env_steps fresh transitions before updates continue"
    );
    Ok(())
}
