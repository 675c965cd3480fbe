//! The selector service: receives every finished episode the actors send over shared memory,
//! keeps per-task success-rate windows and episode statistics, and serves them in `GetStatus`.
//!
//! With `algorithm = "terl"` it also runs PTR selection ([`scoring`]): it follows the learner's
//! policy and critic weights, scores the episodes of tasks whose success gate is open, ranks
//! them in per-task pools of trajectories, sends each full pool's top transitions (in batches
//! of 512) to the learner's TEP buffer over shared memory and appends them to the run's TEP
//! dataset (`runs/<id>/tep-dataset.mcap`, flushed after every delivery, so a killed selector
//! loses at most the selection it was writing).
//!
//! Episodes that never arrive are counted, not silently lost: an actor whose send times out
//! on a full receiver stamps its running count on its next episode (the selector's status
//! shows the sum as `episodes_dropped`), and gaps in each actor's episode indices are the
//! episodes this selector itself never received (`episodes_missed`, and `missed_before` on the
//! next record of that actor in `episodes.mcap`).
//!
//! With `train.eval_every_env_steps > 0` and the learner's address, its `evaluator` thread
//! evaluates the latest policy version deterministically on every task at that interval
//! (`runs/<id>/eval.mcap`, and the last result in `GetStatus`).

#![warn(missing_docs)]

use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use terl_rl::SuccessWindow;
use terl_runtime::Algorithm;
use terl_transport::{
    EpisodeSummary, LossTracker, Message, MessageSink, MessageSource, SelectedBatch,
    SelectedSample, ServiceTransport, Transport, TransportError, SELECTED_PER_BATCH,
};
use terl_wire::{PriorityStats, SelectorBackend, SelectorStatus, TaskSuccess, WeightsKind};
use tonic::Status;
use tracing::Instrument;

pub mod args;
mod evaluator;
pub mod scoring;

use scoring::Scorer;

/// Everything the selector needs to start.
pub type SelectorConfig = terl_runtime::ServiceConfig;

/// Per-task episode statistics: a rolling success window plus running totals.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskEpisodes {
    /// Outcomes (success or not) of the task's last `[train] success_window` episodes.
    pub window: SuccessWindow,
    /// Episodes recorded for the task.
    pub episodes: u64,
    /// Of those, episodes with success at any step.
    pub successes: u64,
    /// Sum of the finite episode returns (non-finite ones are left out).
    pub return_sum: f64,
    /// Sum of the episode lengths, in env steps.
    pub length_sum: u64,
}

/// What the selector knows about the run's episodes.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeStats {
    tasks: Vec<String>,
    per_task: Vec<TaskEpisodes>,
    episodes_seen: u64,
    /// Episodes naming a task outside the run's task list (a misconfigured actor).
    rejected: u64,
    /// Episodes the actors report they could not deliver to every receiver (their loss
    /// stamps, summed over actors and actor restarts).
    episodes_dropped: u64,
    /// Episodes this selector never received: gaps in each actor's episode indices.
    episodes_missed: u64,
}

impl EpisodeStats {
    /// Empty statistics for `tasks` (the run's task list, in task-id order) with success windows of
    /// `window_len` episodes.
    pub fn new(tasks: Vec<String>, window_len: usize) -> Self {
        let empty = TaskEpisodes {
            window: SuccessWindow::new(window_len),
            episodes: 0,
            successes: 0,
            return_sum: 0.0,
            length_sum: 0,
        };
        let per_task = vec![empty; tasks.len()];
        Self {
            tasks,
            per_task,
            episodes_seen: 0,
            rejected: 0,
            episodes_dropped: 0,
            episodes_missed: 0,
        }
    }

    /// Takes the loss counts of the episode stream from the receive loop's tracker.
    pub fn set_losses(&mut self, tracker: &LossTracker) {
        let total = tracker.total();
        self.episodes_dropped = total.reported.messages;
        self.episodes_missed = total.missed;
    }

    /// Records one finished episode.
    pub fn record(&mut self, task: usize, success: bool, episode_return: f64, length: u32) {
        let Some(t) = self.per_task.get_mut(task) else {
            self.rejected += 1;
            return;
        };
        self.episodes_seen += 1;
        t.window.push(success);
        t.episodes += 1;
        t.successes += u64::from(success);
        if episode_return.is_finite() {
            t.return_sum += episode_return;
        }
        t.length_sum += u64::from(length);
    }

    /// Per-task statistics, in task-id order.
    pub fn per_task(&self) -> &[TaskEpisodes] {
        &self.per_task
    }

    /// Success rate over each task's window.
    pub fn task_success(&self) -> Vec<TaskSuccess> {
        self.tasks
            .iter()
            .zip(&self.per_task)
            .map(|(task, t)| TaskSuccess {
                task: task.clone(),
                success_rate: t.window.rate(),
                episodes: t.window.len() as u64,
                ..TaskSuccess::default()
            })
            .collect()
    }
}

/// What PTR selection has done, for status.
#[derive(Debug, Clone, Default)]
struct Selection {
    selected: u64,
    priority: PriorityStats,
    critic_version: u64,
}

/// Newest weights received and not yet loaded, per kind (latest wins).
#[derive(Debug, Default)]
struct WeightSlots {
    policy: Option<(u64, Vec<f32>)>,
    critic: Option<(u64, Vec<f32>)>,
}

#[derive(Debug)]
struct Shared {
    started: Instant,
    run_id: String,
    stats: Mutex<EpisodeStats>,
    selection: Mutex<Selection>,
    weights: Mutex<WeightSlots>,
    stop: AtomicBool,
    /// The newest policy weights, for the evaluator (kept, not taken, unlike `weights`).
    eval_policy: Mutex<Option<(u64, Vec<f32>)>>,
    /// The in-run evaluation log (None when evaluation is off or after shutdown).
    eval_log: Mutex<Option<terl_telemetry::EvalLogWriter>>,
    /// The same evaluations as TensorBoard scalars (`<run_dir>/eval/events.out.tfevents.*`,
    /// keyed by env steps).
    eval_tensorboard: Mutex<Option<terl_telemetry::EventWriter>>,
    /// The latest evaluation and the number of evaluations so far.
    last_eval: Mutex<(Option<terl_wire::EvalResult>, u64)>,
}

#[derive(Debug)]
struct Backend(Arc<Shared>);

impl SelectorBackend for Backend {
    async fn status(&self) -> Result<SelectorStatus, Status> {
        let stats = self
            .0
            .stats
            .lock()
            .map_err(|_| Status::internal("stats lock poisoned"))?;
        let selection = self
            .0
            .selection
            .lock()
            .map_err(|_| Status::internal("selection lock poisoned"))?
            .clone();
        let (last_eval, evaluations) = self
            .0
            .last_eval
            .lock()
            .map_err(|_| Status::internal("evaluation lock poisoned"))?
            .clone();
        Ok(SelectorStatus {
            run_id: self.0.run_id.clone(),
            uptime_seconds: self.0.started.elapsed().as_secs_f64(),
            episodes_seen: stats.episodes_seen,
            task_success: stats.task_success(),
            selected_samples: selection.selected,
            priority: selection.priority,
            critic_version: selection.critic_version,
            last_eval,
            evaluations,
            episodes_dropped: stats.episodes_dropped,
            episodes_missed: stats.episodes_missed,
        })
    }
}

/// The TERL half of the receive loop: scoring, the selected-sample stream, the dataset.
struct Selecting {
    scorer: Scorer,
    sink: Box<dyn MessageSink<SelectedBatch>>,
    batch: Box<SelectedBatch>,
    sequence: u64,
    dataset: terl_telemetry::TepDatasetWriter,
}

impl Selecting {
    fn load_weights(&mut self, shared: &Shared) {
        let fresh = match shared.weights.lock() {
            Ok(mut slots) => std::mem::take(&mut *slots),
            Err(_) => return,
        };
        let estimator = self.scorer.estimator_mut();
        if let Some((version, params)) = fresh.policy {
            if let Err(e) = estimator.set_policy(&params, version) {
                tracing::warn!(version, "ignoring policy weights: {e}");
            }
        }
        if let Some((version, params)) = fresh.critic {
            match estimator.set_critics(&params, version) {
                Ok(()) => tracing::debug!(version, "loaded critic weights"),
                Err(e) => tracing::warn!(version, "ignoring critic weights: {e}"),
            }
        }
    }

    /// Sends the selection of one or more ranked batches (grouped by trajectory, steps
    /// ascending, so the learner can store them as segments) and appends it to the dataset.
    /// `tasks` are the run's task names (samples carry indices into it).
    fn deliver(
        &mut self,
        mut selected: Vec<(f64, SelectedSample)>,
        tasks: &[&str],
    ) -> anyhow::Result<()> {
        if selected.is_empty() {
            return Ok(());
        }
        let log_time = terl_telemetry::unix_nanos();
        for (p, s) in &selected {
            let sample = terl_wire::TepSample {
                task: tasks[usize::from(s.task)].to_string(),
                trajectory_id: s.trajectory_id,
                step: u32::from(s.step_index),
                priority: *p,
                obs: s.obs,
                next_obs: s.next_obs,
                goal_obs: None,
                action: s.action,
                success: s.succeeded(),
                variation: s.variation(),
            };
            self.dataset.write(&sample, log_time)?;
        }
        self.dataset.flush()?;
        selected.sort_by_key(|(_, s)| (s.trajectory_id, s.step_index));
        for chunk in selected.chunks(SELECTED_PER_BATCH) {
            self.batch.len = 0;
            for (_, s) in chunk {
                let _ = self.batch.push(*s);
            }
            self.batch.sequence = self.sequence;
            self.sequence += 1;
            match self.sink.send(&self.batch) {
                Ok(_) => {}
                Err(e @ TransportError::BlockTimeout { .. }) => {
                    // Still in the dataset; the learner was paused longer than the timeout.
                    tracing::warn!("selected samples not delivered: {e}");
                }
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }
}

/// The selector's receive loop: episode summaries in, the episode log, the statistics and (with
/// TERL) PTR selection out, until the stop flag is set.
fn receive_loop<T: Transport>(
    config: &SelectorConfig,
    transport: &T,
    shared: &Shared,
) -> anyhow::Result<()> {
    let mut receiver = EpisodeReceiver::open(config, transport, shared)?;
    while !shared.stop.load(Ordering::Relaxed) {
        if receiver.round(shared)? == 0 {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    receiver.finish()
}

/// Episode summaries received at most per round, so logs, statistics and the status stay
/// current under a burst.
const EPISODES_PER_ROUND: usize = 16;

/// What the receive loop keeps between rounds.
struct EpisodeReceiver<'a> {
    tasks: Vec<&'a str>,
    episodes: Box<dyn MessageSource<EpisodeSummary>>,
    /// With TERL: the PTR scorer, the selected-sample sink and the TEP dataset.
    selecting: Option<Selecting>,
    episode_log: terl_telemetry::EpisodeLogWriter,
    last_flush: Instant,
    last_log: Instant,
    /// Episodes that never arrived: the actors' loss stamps and gaps in their episode indices
    /// (an actor's send gave up on this selector, or on the learner, after the block timeout).
    losses: LossTracker,
    missed_logged: u64,
    /// Per received episode, the episodes of its actor missed just before it.
    gaps: Vec<u64>,
    received: Vec<Box<EpisodeSummary>>,
    spare: Vec<Box<EpisodeSummary>>,
}

impl<'a> EpisodeReceiver<'a> {
    /// Opens the episode source, the episode log and (with TERL) the selection's sink and TEP
    /// dataset; with `--resume`, rebuilds statistics and gates from the run's episode logs.
    fn open<T: Transport>(
        config: &'a SelectorConfig,
        transport: &T,
        shared: &Shared,
    ) -> anyhow::Result<Self> {
        let run = &config.run;
        let episodes = transport.source::<EpisodeSummary>()?;
        let tasks: Vec<&str> = terl_runtime::resolve_tasks(&run.tasks)?;
        let mut selecting = if run.algorithm == Algorithm::Terl {
            let sac = run.sac_config(tasks.len());
            let path = terl_telemetry::fresh_path(&config.run_dir, "tep-dataset");
            let dataset = terl_telemetry::TepDatasetWriter::create(&path)
                .with_context(|| format!("cannot create the TEP dataset {}", path.display()))?;
            tracing::info!(path = %path.display(), "writing selected samples to the TEP dataset");
            Some(Selecting {
                scorer: Scorer::new(run.ptr.clone(), &sac),
                sink: transport.sink::<SelectedBatch>()?,
                batch: Box::new(SelectedBatch::EMPTY),
                sequence: 0,
                dataset,
            })
        } else {
            None
        };
        if config.resume {
            let mut stats = shared
                .stats
                .lock()
                .map_err(|_| anyhow::anyhow!("episode statistics lock poisoned"))?;
            resume_from_logs(
                &config.run_dir,
                &tasks,
                &mut stats,
                selecting.as_mut().map(|s| &mut s.scorer),
            )?;
        }
        let episode_path = terl_telemetry::fresh_path(&config.run_dir, "episodes");
        let episode_log = terl_telemetry::EpisodeLogWriter::create(&episode_path)
            .with_context(|| format!("cannot create the episode log {}", episode_path.display()))?;
        Ok(Self {
            tasks,
            episodes,
            selecting,
            episode_log,
            last_flush: Instant::now(),
            last_log: Instant::now(),
            losses: LossTracker::new(),
            missed_logged: 0,
            gaps: Vec::new(),
            received: Vec::new(),
            spare: Vec::new(),
        })
    }

    /// One round: fresh critic weights for the scorer, up to [`EPISODES_PER_ROUND`] episodes
    /// received, counted, logged, recorded and (with TERL) scored. Returns the episodes received.
    fn round(&mut self, shared: &Shared) -> anyhow::Result<usize> {
        if let Some(sel) = self.selecting.as_mut() {
            sel.load_weights(shared);
        }
        self.receive()?;
        let got = self.received.len();
        self.count_losses();
        self.log_episodes()?;
        self.record(shared);
        self.select(shared)?;
        self.spare.append(&mut self.received);
        self.log_progress(shared);
        Ok(got)
    }

    /// Takes what the source holds, up to [`EPISODES_PER_ROUND`], into `received`.
    fn receive(&mut self) -> anyhow::Result<()> {
        while self.received.len() < EPISODES_PER_ROUND {
            let mut e = self.spare.pop().unwrap_or_else(EpisodeSummary::empty);
            if !self.episodes.try_receive_into(&mut e)? {
                self.spare.push(e);
                break;
            }
            self.received.push(e);
        }
        Ok(())
    }

    /// The received episodes' loss stamps and index gaps; a warning when the total of missed
    /// episodes grew.
    fn count_losses(&mut self) {
        self.gaps.clear();
        let losses = &mut self.losses;
        self.gaps.extend(
            self.received
                .iter()
                .map(|e| losses.observe(e.actor_id, e.episode_index, e.losses())),
        );
        let missed = self.losses.total().missed;
        if missed > self.missed_logged {
            self.missed_logged = missed;
            tracing::warn!(
                episodes_missed = missed,
                episodes_dropped = self.losses.total().reported.messages,
                "episodes never arrived: an actor's send gave up on a full receiver after \
                 cluster.block_timeout_secs (totals so far)"
            );
        }
    }

    /// Appends the received episodes of the run's tasks with a finite return to the episode
    /// log (`episodes.mcap`), flushed at most once a second.
    fn log_episodes(&mut self) -> anyhow::Result<()> {
        let now_ns = terl_telemetry::unix_nanos();
        for (e, &missed_before) in self.received.iter().zip(&self.gaps) {
            let Some(task) = self.tasks.get(usize::from(e.task)) else {
                continue;
            };
            let record = terl_wire::EpisodeSummary {
                task: (*task).to_string(),
                actor_id: u32::from(e.actor_id),
                episode_index: e.episode_index,
                episode_return: f64::from(e.episode_return),
                success: e.succeeded(),
                length: e.length,
                policy_version: e.policy_version,
                guided_steps: u32::from(e.guided_steps).min(e.length),
                missed_before,
            };
            if record.episode_return.is_finite() {
                self.episode_log.write(&record, now_ns)?;
            }
        }
        if self.last_flush.elapsed() >= Duration::from_secs(1) {
            self.last_flush = Instant::now();
            self.episode_log.flush()?;
        }
        Ok(())
    }

    /// The received episodes and the loss counts into the shared statistics (status, gates).
    fn record(&self, shared: &Shared) {
        if let Ok(mut stats) = shared.stats.lock() {
            stats.set_losses(&self.losses);
            for e in &self.received {
                stats.record(
                    usize::from(e.task),
                    e.succeeded(),
                    f64::from(e.episode_return),
                    e.length,
                );
            }
        }
    }

    /// With TERL: scores the received episodes, delivers what PTR selects (learner and TEP
    /// dataset) and publishes the selection's counters.
    fn select(&mut self, shared: &Shared) -> anyhow::Result<()> {
        let Some(sel) = self.selecting.as_mut() else {
            return Ok(());
        };
        let mut chosen = Vec::new();
        for e in &self.received {
            if usize::from(e.task) < self.tasks.len() {
                chosen.extend(sel.scorer.on_episode(e));
            }
        }
        sel.deliver(chosen, &self.tasks)?;
        if let Ok(mut s) = shared.selection.lock() {
            s.selected = sel.scorer.selected;
            s.priority = sel.scorer.priority_stats();
            s.critic_version = sel.scorer.critic_version();
        }
        Ok(())
    }

    /// A progress line every 10 s.
    fn log_progress(&mut self, shared: &Shared) {
        if self.last_log.elapsed() < Duration::from_secs(10) {
            return;
        }
        self.last_log = Instant::now();
        if let Ok(stats) = shared.stats.lock() {
            match &self.selecting {
                Some(sel) => tracing::info!(
                    episodes = stats.episodes_seen,
                    selected = sel.scorer.selected,
                    scored = sel.scorer.priority_stats().scored,
                    unscored_no_weights = sel.scorer.unscored_no_weights,
                    critic_version = sel.scorer.critic_version(),
                    "progress"
                ),
                None => tracing::info!(episodes = stats.episodes_seen, "progress"),
            }
        }
    }

    /// Closes the episode log and the TEP dataset (syncing both).
    fn finish(self) -> anyhow::Result<()> {
        let n = self.episode_log.finish()?;
        tracing::info!(episodes = n, "episode log closed");
        if let Some(sel) = self.selecting {
            let n = sel.dataset.finish()?;
            tracing::info!(samples = n, "TEP dataset closed");
        }
        Ok(())
    }
}

/// `--resume`: rebuilds the success windows, episode totals and PTR gates from the episode
/// logs earlier processes of this run wrote (`episodes.mcap`, `episodes.2.mcap`, …), so gates
/// that were open stay open and windows continue. Episodes of tasks outside this run's task list
/// are skipped; a log cut short by a kill contributes what was flushed. PTR pools that were not
/// full when the earlier process stopped are not recovered (they were never selected).
fn resume_from_logs(
    run_dir: &std::path::Path,
    tasks: &[&str],
    stats: &mut EpisodeStats,
    mut scorer: Option<&mut Scorer>,
) -> anyhow::Result<u64> {
    let paths = terl_telemetry::existing_paths(run_dir, "episodes");
    let mut replayed = 0u64;
    for path in &paths {
        let log = terl_telemetry::read_log::<terl_wire::EpisodeSummary>(path)
            .with_context(|| format!("--resume: cannot read the episode log {}", path.display()))?;
        if log.truncated {
            tracing::warn!(file = %path.display(), episodes = log.records.len(), "episode log was cut short (a killed selector); resuming from what it holds");
        }
        for e in &log.records {
            let Some(task) = tasks.iter().position(|t| *t == e.task) else {
                continue;
            };
            stats.record(task, e.success, e.episode_return, e.length);
            if let Some(s) = scorer.as_deref_mut() {
                s.replay_episode(task, e.success);
            }
            replayed += 1;
        }
    }
    let open: Vec<&str> = match scorer.as_deref() {
        Some(s) => tasks
            .iter()
            .enumerate()
            .filter(|(k, _)| s.gate_open(*k))
            .map(|(_, t)| *t)
            .collect(),
        None => Vec::new(),
    };
    tracing::info!(
        logs = paths.len(),
        episodes = replayed,
        open_gates = ?open,
        "resumed the success windows and PTR gates from the episode logs"
    );
    Ok(replayed)
}

/// Runs the selector on `listener` (already bound, e.g. by [`terl_wire::bind_secured`]) and
/// `transport` (the run's streams: [`terl_transport::RunTransport`] in the binary, a
/// [`terl_transport::MemoryTransport`] on a shared bus in tests) until `shutdown` completes or
/// receiving fails. Writes `<run_dir>/selector.addr`; logs inside a `selector{run=<run id>}`
/// span.
///
/// # Errors
/// `algorithm = "terl"` without the learner's address, an unknown task, the receive loop's
/// error or the gRPC server's.
pub async fn run<T: ServiceTransport>(
    config: SelectorConfig,
    listener: tokio::net::TcpListener,
    transport: T,
    shutdown: impl Future<Output = ()> + Send,
) -> anyhow::Result<()> {
    let span = tracing::info_span!("selector", run = %config.run_id);
    run_in_span(config, listener, transport, shutdown, span.clone())
        .instrument(span)
        .await
}

#[allow(clippy::too_many_lines)] // the service's start-up in order (transport, gRPC, threads, shutdown)
async fn run_in_span<T: ServiceTransport>(
    config: SelectorConfig,
    listener: tokio::net::TcpListener,
    transport: T,
    shutdown: impl Future<Output = ()> + Send,
    span: tracing::Span,
) -> anyhow::Result<()> {
    anyhow::ensure!(
        config.run.algorithm != Algorithm::Terl || config.learner_addr.is_some(),
        "algorithm = \"terl\" needs the learner's address (--learner-addr): PTR scoring follows \
         its policy and critic weights"
    );
    let tasks = terl_runtime::resolve_tasks(&config.run.tasks)?
        .into_iter()
        .map(str::to_owned)
        .collect();
    let serve_options = terl_wire::ServeOptions {
        security: config.server_security.clone(),
        ..terl_wire::ServeOptions::default()
    };
    terl_runtime::service::announce(&listener, &config.run_dir, "selector", &config.run_id)?;
    let shared = Arc::new(Shared {
        started: Instant::now(),
        run_id: config.run_id.clone(),
        stats: Mutex::new(EpisodeStats::new(tasks, config.run.train.success_window)),
        selection: Mutex::new(Selection::default()),
        weights: Mutex::new(WeightSlots::default()),
        stop: AtomicBool::new(false),
        eval_policy: Mutex::new(None),
        eval_log: Mutex::new(None),
        eval_tensorboard: Mutex::new(None),
        last_eval: Mutex::new((None, 0)),
    });
    let terl = config.run.algorithm == Algorithm::Terl;
    let evaluating = config.run.train.eval_every_env_steps > 0 && config.learner_addr.is_some();
    if config.run.train.eval_every_env_steps > 0 && config.learner_addr.is_none() {
        tracing::warn!(
            "no --learner-addr: in-run evaluation (train.eval_every_env_steps) is off, since \
             the evaluator follows the learner's policy weights"
        );
    }
    if evaluating {
        let path = terl_telemetry::fresh_path(&config.run_dir, "eval");
        let log = terl_telemetry::EvalLogWriter::create(&path)
            .with_context(|| format!("cannot create the evaluation log {}", path.display()))?;
        tracing::info!(path = %path.display(), "writing in-run evaluations");
        let tb_dir = config.run_dir.join("eval");
        let tb = terl_telemetry::EventWriter::create(&tb_dir, "evaluator").with_context(|| {
            format!(
                "cannot create the evaluation's TensorBoard file in {}",
                tb_dir.display()
            )
        })?;
        *shared
            .eval_tensorboard
            .lock()
            .map_err(|_| anyhow::anyhow!("evaluation log lock poisoned"))? = Some(tb);
        *shared
            .eval_log
            .lock()
            .map_err(|_| anyhow::anyhow!("evaluation log lock poisoned"))? = Some(log);
    }
    let follower = match &config.learner_addr {
        Some(addr) if terl || evaluating => {
            let shared = Arc::clone(&shared);
            let kinds = if terl {
                vec![WeightsKind::Policy, WeightsKind::Critic]
            } else {
                vec![WeightsKind::Policy]
            };
            let options = terl_wire::ClientOptions {
                max_message_bytes: config.run.cluster.max_message_bytes(),
                security: config.client_security.clone(),
                watcher: None,
            };
            Some(tokio::spawn(
                terl_wire::follow_weights_with(addr.clone(), kinds, options, move |w| {
                    let (kind, version) = (w.kind(), w.version());
                    let flat: Vec<f32> = w.into_flat();
                    if kind == WeightsKind::Policy && evaluating {
                        if let Ok(mut p) = shared.eval_policy.lock() {
                            *p = Some((version, flat.clone()));
                        }
                    }
                    if !terl {
                        return;
                    }
                    if let Ok(mut slots) = shared.weights.lock() {
                        match kind {
                            WeightsKind::Critic => slots.critic = Some((version, flat)),
                            _ => slots.policy = Some((version, flat)),
                        }
                    }
                })
                .in_current_span(),
            ))
        }
        _ => None,
    };
    let evaluator = match (&config.learner_addr, evaluating) {
        (Some(addr), true) => {
            let (shared, addr, config) = (Arc::clone(&shared), addr.clone(), config.clone());
            let span = span.clone();
            Some(
                std::thread::Builder::new()
                    .name("evaluator".into())
                    .spawn(move || span.in_scope(|| evaluator::run(&config, &shared, &addr)))?,
            )
        }
        _ => None,
    };
    let mut receiver = {
        let shared = Arc::clone(&shared);
        terl_runtime::service::Worker::spawn("episodes", "episode receiver", span, move || {
            receive_loop(&config, &transport, &shared)
        })?
    };
    let backend = Backend(Arc::clone(&shared));
    let served = terl_runtime::service::serve_until(shutdown, &mut receiver, |stop| {
        terl_wire::serve_selector_with(listener, backend, stop, serve_options)
    })
    .await;
    shared.stop.store(true, Ordering::Relaxed);
    if let Some(f) = follower {
        f.abort();
    }
    let received = receiver.join().await;
    if let Some(e) = evaluator {
        // The evaluator sees `stop` within one environment step or one status poll.
        if tokio::task::spawn_blocking(move || e.join())
            .await?
            .is_err()
        {
            tracing::warn!("evaluator panicked");
        }
    }
    let eval_log = shared.eval_log.lock().ok().and_then(|mut l| l.take());
    if let Some(log) = eval_log {
        let n = log.finish()?;
        tracing::info!(evaluations = n, "evaluation log closed");
    }
    served.context("gRPC server")?;
    received
}

#[cfg(test)]
mod tests {
    use super::*;

    fn episode(task: &str, index: u64, success: bool) -> terl_wire::EpisodeSummary {
        terl_wire::EpisodeSummary {
            task: task.into(),
            actor_id: 0,
            episode_index: index,
            episode_return: 1.0,
            success,
            length: 500,
            policy_version: 1,
            guided_steps: 0,
            missed_before: 0,
        }
    }

    /// Windows and gates continue from the logs of earlier processes (two files, the second
    /// cut short as by a kill); an unknown task in a log is skipped.
    #[test]
    fn resume_rebuilds_windows_and_gates_from_the_episode_logs() {
        let dir = tempfile::tempdir().unwrap();
        let mut first =
            terl_telemetry::EpisodeLogWriter::create(dir.path().join("episodes.mcap")).unwrap();
        // reach: 4 successes (gate threshold 0.75 over a window of 4: opens); push: 1 of 4.
        for k in 0..4 {
            first.write(&episode("reach-v3", k, true), k).unwrap();
            first.write(&episode("push-v3", k, k == 0), k).unwrap();
        }
        first.write(&episode("door-open-v3", 9, true), 9).unwrap();
        first.finish().unwrap();
        let mut second =
            terl_telemetry::EpisodeLogWriter::create(dir.path().join("episodes.2.mcap")).unwrap();
        // After the gate opened, reach fails twice: a latched gate stays open.
        for k in 4..6 {
            second.write(&episode("reach-v3", k, false), k).unwrap();
        }
        second.flush().unwrap();
        std::mem::forget(second); // killed: never finished

        let tasks = ["reach-v3", "push-v3"];
        let mut stats = EpisodeStats::new(tasks.iter().map(|t| t.to_string()).collect(), 4);
        let ptr = terl_rl::ptr::PtrConfig {
            success_threshold: 0.75,
            success_window: 4,
            ..terl_rl::ptr::PtrConfig::default()
        };
        let sac = terl_rl::SacConfig {
            obs_dim: terl_transport::OBS_DIM,
            act_dim: terl_transport::ACTION_DIM,
            num_tasks: 2,
            ..terl_rl::SacConfig::default()
        };
        let mut scorer = Scorer::new(ptr, &sac);
        let n = resume_from_logs(dir.path(), &tasks, &mut stats, Some(&mut scorer)).unwrap();
        assert_eq!(n, 10);
        assert!(scorer.gate_open(0) && !scorer.gate_open(1));
        let ts = stats.task_success();
        assert_eq!((ts[0].success_rate, ts[0].episodes), (0.5, 4));
        assert_eq!((ts[1].success_rate, ts[1].episodes), (0.25, 4));
        assert_eq!(stats.per_task()[0].episodes, 6);
    }

    #[test]
    fn windows_roll_and_unknown_tasks_are_counted() {
        let mut s = EpisodeStats::new(vec!["a".into(), "b".into()], 2);
        s.record(0, true, 10.0, 500);
        s.record(0, false, 5.0, 500);
        s.record(0, false, 5.0, 500);
        s.record(1, true, 1.0, 500);
        s.record(7, true, 1.0, 500);
        let ts = s.task_success();
        assert_eq!((ts[0].success_rate, ts[0].episodes), (0.0, 2));
        assert_eq!((ts[1].success_rate, ts[1].episodes), (1.0, 1));
        assert_eq!(s.per_task()[0].episodes, 3);
        assert_eq!(s.episodes_seen, 4);
        assert_eq!(s.rejected, 1);
    }
}
