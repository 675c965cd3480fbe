//! The training loop of the learner process (its own thread).
//!
//! One round: drain transition batches from shared memory while the rate limiter allows
//! inserts (when it does not, batches stay queued and actors meet back-pressure), drain
//! finished episodes (success windows) and selected samples, run updates while the limiter
//! allows samples, publish weights every `publish_every_updates`, refresh the status snapshot,
//! write a checkpoint when one is due or requested. Policy versions are the learner's update
//! count at publication, so a transition's staleness is "updates behind" directly.

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_rl::replay::MultiTaskReplay;
use terl_rl::{Batch, Sac, SacError, SuccessWindow};
use terl_runtime::{Algorithm, OnCheckpointError};
use terl_transport::{
    flags, EpisodeSummary, Message, MessageSource, RateLimiter, RunTransport, SelectedBatch,
    Staleness, TransitionBatch, Transport, ACTION_DIM, OBS_DIM, TRANSITIONS_PER_BATCH,
};
use terl_wire::{
    ActorStats, CheckpointRequest, CheckpointSaved, LearnerStatus, TaskSuccess, WeightHub, Weights,
    WeightsKind,
};

use crate::checkpoint::{self, Checkpointer, LearnerState, RngState, Snapshot};
use crate::metrics::MetricsLog;
use crate::planner::PlannerTrainer;
use crate::{LearnerConfig, Shared};

/// A `SaveCheckpoint` request handed to the trainer thread, with where to send the answer.
#[derive(Debug)]
pub struct CheckpointJob {
    pub request: CheckpointRequest,
    pub reply: tokio::sync::oneshot::Sender<Result<CheckpointSaved, String>>,
}

/// Batches drained per round at most, so updates and status are never starved.
const MAX_BATCHES_PER_ROUND: usize = 16;
/// Updates per round at most, so queued batches are drained regularly.
const MAX_UPDATES_PER_ROUND: usize = 16;
/// Status snapshot refresh period; rates are computed over [`RATE_WINDOW`].
const STATUS_EVERY: Duration = Duration::from_millis(250);
const RATE_WINDOW: Duration = Duration::from_secs(2);

#[derive(Debug, Default)]
struct ActorTrack {
    env_steps: u64,
    policy_version: u64,
    last_seen: Option<Instant>,
    /// (time, env_steps) at the start of the current rate window.
    window: Option<(Instant, u64)>,
    steps_per_second: f64,
}

/// Training state that is not the network itself.
struct Counters {
    env_steps: u64,
    actors: BTreeMap<u16, ActorTrack>,
    windows: Vec<SuccessWindow>,
    staleness: Staleness,
    /// Staleness over the last completed rate window (what status shows).
    staleness_shown: Staleness,
    rejected_batches: u64,
    failed_updates: u64,
    failed_in_a_row: u64,
    selected_samples: u64,
    policy_version: u64,
    critic_version: u64,
    updates_window: (Instant, u64),
    updates_per_second: f64,
    /// Per task, `(guided, all)` env steps in the current rate window.
    guidance_window: Vec<(u64, u64)>,
    /// Per task, the guided share of the last completed window.
    guidance_shown: Vec<f64>,
    guided_steps: u64,
    /// Loss stamps of everything received (status: `*_dropped`).
    inbound: crate::losses::Inbound,
    checkpoint_failures: u64,
    /// The checkpoint this learner resumed from and its update count.
    resumed: Option<(PathBuf, u64)>,
}

/// Batches taken out of shared memory and not yet in replay, one queue per actor.
///
/// iceoryx2's subscriber always serves the first publisher that has data, so under
/// back-pressure (the rate limiter refusing inserts) a learner that received one batch at a
/// time would only ever hear from one actor and starve the rest. Instead, whenever at most
/// `low_water` batches are staged, the learner empties every actor's shared-memory queue into
/// the staging area (at most `low_water` more, one queue's worth per actor), and inserts into
/// replay round-robin over actors. Every actor thus delivers its queue once per cycle.
struct Staging {
    low_water: usize,
    queues: BTreeMap<u16, VecDeque<Box<TransitionBatch>>>,
    staged: usize,
    cursor: u16,
    free: Vec<Box<TransitionBatch>>,
}

impl Staging {
    fn new(low_water: usize) -> Self {
        Self {
            low_water: low_water.max(1),
            queues: BTreeMap::new(),
            staged: 0,
            cursor: 0,
            free: Vec::new(),
        }
    }

    /// Drains the source when the staging area is low; true if anything arrived.
    fn fill(
        &mut self,
        source: &mut dyn MessageSource<TransitionBatch>,
    ) -> Result<bool, terl_transport::TransportError> {
        if self.staged > self.low_water {
            return Ok(false);
        }
        let mut got = false;
        while self.staged < 2 * self.low_water {
            let mut b = self.free.pop().unwrap_or_else(TransitionBatch::empty);
            if !source.try_receive_into(&mut b)? {
                self.free.push(b);
                break;
            }
            got = true;
            self.staged += 1;
            self.queues.entry(b.actor_id).or_default().push_back(b);
        }
        Ok(got)
    }

    /// The next batch, round-robin over actors.
    fn next(&mut self) -> Option<Box<TransitionBatch>> {
        let key = self
            .queues
            .range(self.cursor..)
            .chain(self.queues.range(..self.cursor))
            .find(|(_, q)| !q.is_empty())
            .map(|(&k, _)| k)?;
        self.cursor = key.wrapping_add(1);
        self.staged -= 1;
        self.queues.get_mut(&key).and_then(VecDeque::pop_front)
    }

    fn recycle(&mut self, b: Box<TransitionBatch>) {
        if self.free.len() < 2 * self.low_water {
            self.free.push(b);
        }
    }
}

/// Loads a batch into replay. Rejects (and counts) batches with an unknown task or
/// non-finite values as a whole: they come from a broken actor.
fn ingest(
    batch: &TransitionBatch,
    num_tasks: usize,
    replay: &mut MultiTaskReplay,
    c: &mut Counters,
) -> u64 {
    c.inbound.batch(batch);
    let ts = batch.as_slice();
    let valid = ts.iter().all(|t| {
        (t.task as usize) < num_tasks
            && t.reward.is_finite()
            && t.obs
                .iter()
                .chain(&t.next_obs)
                .chain(&t.action)
                .all(|v| v.is_finite())
    });
    if !valid {
        c.rejected_batches += 1;
        return 0;
    }
    let now = Instant::now();
    for t in ts {
        let guided = t.flags & flags::GUIDED != 0;
        let g = &mut c.guidance_window[t.task as usize];
        g.0 += u64::from(guided);
        g.1 += 1;
        c.guided_steps += u64::from(guided);
        replay.push(
            t.task as usize,
            &t.obs,
            &t.action,
            t.reward,
            &t.next_obs,
            t.terminated(),
        );
        c.staleness.record(c.policy_version, t.policy_version);
    }
    let n = ts.len() as u64;
    c.env_steps += n;
    let track = c.actors.entry(batch.actor_id).or_default();
    track.env_steps += n;
    if let Some(last) = ts.last() {
        track.policy_version = last.policy_version;
    }
    track.last_seen = Some(now);
    n
}

fn sac_weights(sac: &Sac<f32>, kind: WeightsKind, version: u64) -> anyhow::Result<Weights> {
    let tensors = match kind {
        WeightsKind::Critic => sac.critic_tensors(),
        _ => sac.policy_tensors(),
    };
    crate::to_weights(kind, version, sac.updates(), tensors)
}

// The learner loop; splitting it belongs to the trainer.rs split of this issue, not here.
#[allow(clippy::too_many_lines)]
pub(crate) fn run(
    config: &LearnerConfig,
    shared: &Shared,
    hub: &WeightHub,
    checkpoint_jobs: &mpsc::Receiver<CheckpointJob>,
) -> anyhow::Result<()> {
    let run = &config.run;
    let tasks = terl_runtime::resolve_tasks(&run.tasks)?;
    let nt = tasks.len();
    let mut sac_config = run.sac.clone();
    sac_config.obs_dim = OBS_DIM;
    sac_config.act_dim = ACTION_DIM;
    sac_config.num_tasks = nt;
    let mut sac = Sac::new(sac_config.clone())?;

    let transport_config = run
        .cluster
        .transport_config(config.run_id.clone(), config.num_actors);
    let transport = RunTransport::open(transport_config, "learner")?;
    let mut transitions: Box<dyn MessageSource<TransitionBatch>> =
        transport.source::<TransitionBatch>()?;
    let mut staging = Staging::new(config.num_actors * run.cluster.buffer_batches);
    let mut episodes = transport.source::<EpisodeSummary>()?;
    let mut selected = transport.source::<SelectedBatch>()?;
    let mut episode = EpisodeSummary::empty();
    let mut selected_batch = SelectedBatch::empty();
    let terl = run.algorithm == Algorithm::Terl;
    let checkpoint_dir = config.run_dir.join("checkpoints");
    let resume_from = if config.resume {
        let found = checkpoint::newest_intact(&checkpoint_dir)?;
        if found.is_none() {
            tracing::warn!(dir = %checkpoint_dir.display(), "--resume: the run has no checkpoint yet; starting fresh");
        }
        found
    } else {
        None
    };
    let mut planner = if terl {
        let mut p = PlannerTrainer::new(run.tep.clone(), nt, run.train.seed)?;
        let mut datasets = config.tep_datasets.clone();
        if resume_from.is_some() {
            // The TEP buffer is not in the checkpoint: the run's own dataset holds every
            // selected sample it received (one file per selector start).
            datasets.extend(terl_telemetry::existing_paths(
                &config.run_dir,
                "tep-dataset",
            ));
        }
        crate::dataset::load_all(&datasets, &tasks, &mut p)?;
        Some(p)
    } else {
        None
    };

    let spi = run.samples_per_insert();
    let mut limiter = RateLimiter::new(
        spi,
        run.train.warmup_env_steps,
        run.rate_error_buffer(TRANSITIONS_PER_BATCH),
    )?;
    let capacity = run.train.replay_capacity_per_task;
    let mut replay = MultiTaskReplay::new(nt, capacity, OBS_DIM, ACTION_DIM);
    let mut batch = Batch::with_capacity(sac_config.batch_size, OBS_DIM, ACTION_DIM);
    let mut rng = ChaCha8Rng::seed_from_u64(run.train.seed ^ 0x1ea7_7e55);
    let mut metrics = MetricsLog::create(&config.run_dir)?;
    let mut checkpointer = Checkpointer::open(checkpoint_dir, run.cluster.keep_checkpoints)?;
    let checkpoint_every = (run.cluster.checkpoint_every_secs > 0.0)
        .then(|| Duration::from_secs_f64(run.cluster.checkpoint_every_secs));
    let mut last_checkpoint = Instant::now();

    let start = Instant::now();
    let window_len = run.train.success_window.max(1);
    let mut c = Counters {
        env_steps: 0,
        actors: BTreeMap::new(),
        windows: vec![SuccessWindow::new(window_len); nt],
        staleness: Staleness::default(),
        staleness_shown: Staleness::default(),
        rejected_batches: 0,
        failed_updates: 0,
        failed_in_a_row: 0,
        selected_samples: 0,
        policy_version: 0,
        critic_version: 0,
        updates_window: (start, 0),
        updates_per_second: 0.0,
        guidance_window: vec![(0, 0); nt],
        guidance_shown: vec![0.0; nt],
        guided_steps: 0,
        inbound: crate::losses::Inbound::default(),
        checkpoint_failures: 0,
        resumed: None,
    };
    if let Some(found) = resume_from {
        check_compatible(&found, &tasks, run.algorithm)?;
        restore(
            found,
            &mut sac,
            planner.as_mut(),
            &mut rng,
            &mut c,
            window_len,
        )?;
        // Actors and the selector get the restored networks at once (updates only continue
        // once the replay buffer holds `warmup_env_steps` fresh transitions).
        let version = sac.updates();
        hub.publish(&sac_weights(&sac, WeightsKind::Policy, version)?)?;
        c.policy_version = version;
        if terl {
            hub.publish(&sac_weights(&sac, WeightsKind::Critic, version)?)?;
            c.critic_version = version;
        }
        if let Some(p) = planner.as_mut() {
            if let Some(w) = p.weights_to_publish()? {
                hub.publish(&w)?;
            }
        }
    }
    let mut last_status = start - STATUS_EVERY;
    let mut last_log = start;
    tracing::info!(
        tasks = nt,
        samples_per_insert = spi,
        warmup = run.train.warmup_env_steps,
        publish_every = run.cluster.publish_every_updates,
        algorithm = run.algorithm.as_str(),
        "trainer started"
    );

    let budget = run.train.total_env_steps;
    while !shared.stop.load(Ordering::Relaxed) {
        if budget > 0 && c.env_steps >= budget {
            tracing::info!(
                env_steps = c.env_steps,
                updates = sac.updates(),
                "training budget reached (train.total_env_steps); stopping"
            );
            break;
        }
        let mut busy = staging.fill(transitions.as_mut())?;
        for _ in 0..MAX_BATCHES_PER_ROUND {
            if !limiter.can_insert(TRANSITIONS_PER_BATCH as u64) {
                break;
            }
            let Some(b) = staging.next() else { break };
            let n = ingest(&b, nt, &mut replay, &mut c);
            staging.recycle(b);
            limiter.record_insert(n);
            busy = true;
        }
        while episodes.try_receive_into(&mut episode)? {
            let e = &*episode;
            c.inbound.episode(e);
            if let Some(w) = c.windows.get_mut(e.task as usize) {
                w.push(e.succeeded());
            }
            busy = true;
        }
        while selected.try_receive_into(&mut selected_batch)? {
            let s = &*selected_batch;
            c.inbound.selected(s);
            c.selected_samples += match planner.as_mut() {
                Some(p) => p.ingest_batch(s),
                None => s.as_slice().len() as u64,
            };
            busy = true;
        }

        for _ in 0..MAX_UPDATES_PER_ROUND {
            if !limiter.can_sample(1) {
                break;
            }
            replay.sample_into(sac_config.batch_size, &mut rng, &mut batch);
            limiter.record_sample(1);
            busy = true;
            match sac.update(&batch) {
                Ok(stats) => {
                    c.failed_in_a_row = 0;
                    metrics.record_update(&stats);
                }
                Err(SacError::NonFiniteBatch { .. }) => {}
                Err(e @ (SacError::NonFiniteLoss { .. } | SacError::NonFiniteGradient { .. })) => {
                    c.failed_updates += 1;
                    c.failed_in_a_row += 1;
                    if c.failed_in_a_row >= run.train.max_consecutive_failed_updates {
                        return Err(e).context("too many failed updates in a row");
                    }
                }
                Err(e) => return Err(e.into()),
            }
        }
        if let Some(p) = planner.as_mut() {
            if p.train(sac.updates())? > 0 {
                busy = true;
            }
        }
        if sac.updates() >= c.policy_version + run.cluster.publish_every_updates {
            let version = sac.updates();
            hub.publish(&sac_weights(&sac, WeightsKind::Policy, version)?)?;
            c.policy_version = version;
            if terl && version >= c.critic_version + run.cluster.critic_publish_every_updates {
                hub.publish(&sac_weights(&sac, WeightsKind::Critic, version)?)?;
                c.critic_version = version;
            }
            if let Some(p) = planner.as_mut() {
                if let Some(w) = p.weights_to_publish()? {
                    hub.publish(&w)?;
                }
            }
        }

        while let Ok(job) = checkpoint_jobs.try_recv() {
            let name = match &job.request.label {
                Some(label) => format!("{label}-update-{:010}", sac.updates()),
                None => format!("requested-update-{:010}", sac.updates()),
            };
            let answer = Snapshot::new(
                &sac,
                planner.as_ref().map(PlannerTrainer::checkpoint_tensors),
                &learner_state(&tasks, run.algorithm, &c, &rng, planner.as_ref()),
            )
            .and_then(|snapshot| checkpointer.write(&name, &snapshot))
            .map(|path| CheckpointSaved {
                path: path.display().to_string(),
                learner_update: sac.updates(),
                policy_version: c.policy_version,
            })
            .map_err(|e| format!("{e:#}"));
            let _ = job.reply.send(answer);
        }
        if checkpoint_every.is_some_and(|every| last_checkpoint.elapsed() >= every) {
            last_checkpoint = Instant::now();
            let written = Snapshot::new(
                &sac,
                planner.as_ref().map(PlannerTrainer::checkpoint_tensors),
                &learner_state(&tasks, run.algorithm, &c, &rng, planner.as_ref()),
            )
            .and_then(|snapshot| checkpointer.periodic(sac.updates(), &snapshot))
            .and_then(|path| {
                if let Some(p) = &planner {
                    let (tensors, meta) = p.tool_file()?;
                    checkpointer.planner(tensors, &meta)?;
                }
                Ok(path)
            });
            match written {
                Ok(path) => {
                    tracing::info!(path = %path.display(), updates = sac.updates(), "checkpoint")
                }
                Err(e) => {
                    c.checkpoint_failures += 1;
                    tracing::error!(failures = c.checkpoint_failures, "{e:#}");
                    if run.cluster.on_checkpoint_error == OnCheckpointError::Stop {
                        return Err(e).context(
                            "stopping: a checkpoint could not be written \
                             (cluster.on_checkpoint_error = \"stop\"; \"continue\" keeps training)",
                        );
                    }
                }
            }
        }

        let now = Instant::now();
        if now - last_status >= STATUS_EVERY {
            last_status = now;
            let window_closed = refresh_rates(&mut c, sac.updates(), now);
            if window_closed {
                if let Some(p) = planner.as_mut() {
                    p.roll_window();
                }
            }
            let mut status = snapshot(config, &tasks, &c, &sac, &replay, capacity, now);
            c.inbound.fill(&mut status);
            status.algorithm = run.algorithm.as_str().to_string();
            if let Some(p) = &planner {
                status.tep_updates = p.updates();
                status.planner_version = p.published_version();
                status.tep_buffer_size = p.buffer_len() as u64;
                status.tep_buffer_capacity = p.buffer_capacity() as u64;
                status.tep_f_loss = p.shown_f_loss;
                status.tep_an_loss = p.shown_an_loss;
                status.tep_target_mean = p.shown_target_mean;
                status.tep_goal_distance_mean = p.shown_goal_distance_mean;
            }
            if now - last_log >= Duration::from_secs(10) {
                last_log = now;
                tracing::info!(
                    updates = status.updates,
                    updates_per_second = format!("{:.0}", status.updates_per_second),
                    env_steps = status.env_steps_total,
                    replay = status.replay_size,
                    policy_version = status.policy_version,
                    staleness_mean = format!("{:.0}", status.staleness_mean),
                    tep_updates = status.tep_updates,
                    tep_buffer = status.tep_buffer_size,
                    tep_f_loss = format!("{:.3}", status.tep_f_loss),
                    tep_target_mean = format!("{:.2}", status.tep_target_mean),
                    tep_goal_distance_mean = format!("{:.2}", status.tep_goal_distance_mean),
                    guided_steps = status.guided_steps,
                    "progress"
                );
            }
            if window_closed {
                metrics.write_window(&status)?;
            }
            if let Ok(mut s) = shared.status.lock() {
                *s = status;
            }
        }
        if !busy {
            std::thread::sleep(Duration::from_micros(500));
        }
    }

    metrics.finish()?;
    let snapshot = Snapshot::new(
        &sac,
        planner.as_ref().map(PlannerTrainer::checkpoint_tensors),
        &learner_state(&tasks, run.algorithm, &c, &rng, planner.as_ref()),
    )?;
    let path = checkpointer.write("final", &snapshot)?;
    if let Some(p) = &planner {
        let (tensors, meta) = p.tool_file()?;
        checkpointer.planner(tensors, &meta)?;
    }
    tracing::info!(path = %path.display(), updates = sac.updates(), env_steps = c.env_steps, "trainer stopped; final checkpoint written");
    Ok(())
}

/// The learner's counters for a checkpoint.
fn learner_state(
    tasks: &[&str],
    algorithm: Algorithm,
    c: &Counters,
    rng: &ChaCha8Rng,
    planner: Option<&PlannerTrainer>,
) -> LearnerState {
    LearnerState {
        tasks: tasks.iter().map(|t| (*t).to_string()).collect(),
        algorithm: algorithm.as_str().to_string(),
        env_steps: c.env_steps,
        policy_version: c.policy_version,
        critic_version: c.critic_version,
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
    window_len: usize,
) -> anyhow::Result<()> {
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
    c.policy_version = state.policy_version;
    c.critic_version = state.critic_version;
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
    tracing::info!(
        checkpoint = %path,
        updates = found.updates,
        env_steps = state.env_steps,
        "resumed; the replay buffer refills with warmup_env_steps fresh transitions before updates continue"
    );
    Ok(())
}

/// Refreshes the windowed rates; true when a window closed.
fn refresh_rates(c: &mut Counters, updates: u64, now: Instant) -> bool {
    let (t0, u0) = c.updates_window;
    let dt = (now - t0).as_secs_f64();
    let closed = now - t0 >= RATE_WINDOW;
    if closed {
        c.updates_per_second = (updates - u0) as f64 / dt;
        c.updates_window = (now, updates);
        c.staleness_shown = std::mem::take(&mut c.staleness);
        for (shown, w) in c.guidance_shown.iter_mut().zip(&mut c.guidance_window) {
            if w.1 > 0 {
                *shown = w.0 as f64 / w.1 as f64;
            }
            *w = (0, 0);
        }
    }
    for track in c.actors.values_mut() {
        match track.window {
            None => track.window = Some((now, track.env_steps)),
            Some((t0, s0)) if now - t0 >= RATE_WINDOW => {
                track.steps_per_second = (track.env_steps - s0) as f64 / (now - t0).as_secs_f64();
                track.window = Some((now, track.env_steps));
            }
            Some(_) => {}
        }
    }
    closed
}

fn snapshot(
    config: &LearnerConfig,
    tasks: &[&str],
    c: &Counters,
    sac: &Sac<f32>,
    replay: &MultiTaskReplay,
    capacity: usize,
    now: Instant,
) -> LearnerStatus {
    LearnerStatus {
        run_id: config.run_id.clone(),
        uptime_seconds: 0.0,
        updates: sac.updates(),
        updates_per_second: c.updates_per_second,
        env_steps_total: c.env_steps,
        actors: c
            .actors
            .iter()
            .map(|(&id, t)| ActorStats {
                actor_id: u32::from(id),
                env_steps: t.env_steps,
                env_steps_per_second: t.steps_per_second,
                policy_version: t.policy_version,
                seconds_since_seen: t.last_seen.map_or(0.0, |s| (now - s).as_secs_f64()),
                ..ActorStats::default()
            })
            .collect(),
        replay_size: replay.total_len() as u64,
        replay_capacity: (capacity * tasks.len()) as u64,
        task_success: tasks
            .iter()
            .zip(&c.windows)
            .zip(&c.guidance_shown)
            .map(|((task, w), &guidance_rate)| TaskSuccess {
                task: (*task).to_string(),
                success_rate: w.rate(),
                episodes: w.len() as u64,
                guidance_rate,
            })
            .collect(),
        staleness_mean: c.staleness_shown.mean(),
        staleness_max: c.staleness_shown.max,
        rejected_batches: c.rejected_batches + sac.rejected_batches(),
        policy_version: c.policy_version,
        selected_samples: c.selected_samples,
        guided_steps: c.guided_steps,
        resumed_from: c
            .resumed
            .as_ref()
            .map(|(p, _)| p.display().to_string())
            .unwrap_or_default(),
        resumed_at_update: c.resumed.as_ref().map_or(0, |(_, u)| *u),
        checkpoint_failures: c.checkpoint_failures,
        ..LearnerStatus::default()
    }
}
