//! Status and metrics: the learner's counters, the windowed rates, the `GetStatus` snapshot
//! the trainer refreshes a few times a second, the `progress` log line and the metrics log's
//! windows.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use terl_rl::replay::MultiTaskReplay;
use terl_rl::{Sac, SuccessWindow};
use terl_runtime::Algorithm;
use terl_transport::Staleness;
use terl_wire::{ActorStats, LearnerStatus, TaskSuccess};

use crate::metrics::MetricsLog;
use crate::planner::PlannerTrainer;
use crate::Shared;

/// Status snapshot refresh period; rates are computed over [`RATE_WINDOW`].
const STATUS_EVERY: Duration = Duration::from_millis(250);
const RATE_WINDOW: Duration = Duration::from_secs(2);
/// Period of the `progress` log line.
const LOG_EVERY: Duration = Duration::from_secs(10);

#[derive(Debug, Default)]
pub(crate) struct ActorTrack {
    pub(crate) env_steps: u64,
    pub(crate) policy_version: u64,
    pub(crate) last_seen: Option<Instant>,
    /// (time, env_steps) at the start of the current rate window.
    window: Option<(Instant, u64)>,
    steps_per_second: f64,
}

/// One task's TERL guidance (Eq. 15) over a rate window, summed from the flags and fields the
/// actors stamp on each transition (`terl_transport::flags::GUIDED`, `GUIDANCE_ACTIVE`,
/// `COMPARED`, `NOT_IMPROVING`, σ^N and ‖AN − π‖).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct GuidanceWindow {
    /// Env steps of the task, and of them guided.
    pub(crate) steps: u64,
    pub(crate) guided: u64,
    /// Steps on which the planner could act, and the sum of their σ^N.
    pub(crate) active: u64,
    pub(crate) probability_sum: f64,
    /// Steps that compared `f_t` with `f_{t−1}`, and of them `f_t ≥ f_{t−1}`.
    pub(crate) compared: u64,
    pub(crate) not_improving: u64,
    /// Sum of ‖AN − π‖ over the guided steps.
    pub(crate) action_gap_sum: f64,
}

impl GuidanceWindow {
    /// Counts one transition.
    pub(crate) fn record(&mut self, t: &terl_transport::Transition) {
        use terl_transport::flags;
        self.steps += 1;
        if t.flags & flags::GUIDED != 0 {
            self.guided += 1;
            self.action_gap_sum += t.action_gap();
        }
        if t.flags & flags::GUIDANCE_ACTIVE != 0 {
            self.active += 1;
            self.probability_sum += t.guidance_probability();
        }
        if t.flags & flags::COMPARED != 0 {
            self.compared += 1;
            self.not_improving += u64::from(t.flags & flags::NOT_IMPROVING != 0);
        }
    }

    /// The window's rates (a `None` where its denominator is 0).
    pub(crate) fn shown(&self) -> GuidanceShown {
        let ratio = |a: f64, b: u64| if b > 0 { Some(a / b as f64) } else { None };
        GuidanceShown {
            rate: ratio(self.guided as f64, self.steps).unwrap_or(0.0),
            probability: ratio(self.probability_sum, self.active).map(|p| p.clamp(0.0, 1.0)),
            not_improving_rate: ratio(self.not_improving as f64, self.compared),
            action_gap: ratio(self.action_gap_sum, self.guided)
                .map(|g| g.clamp(0.0, terl_transport::ACTION_GAP_SCALE)),
            compared: self.compared,
        }
    }
}

/// What status shows of one task's guidance: [`GuidanceWindow::shown`] of the last window.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct GuidanceShown {
    pub(crate) rate: f64,
    pub(crate) probability: Option<f64>,
    pub(crate) not_improving_rate: Option<f64>,
    pub(crate) action_gap: Option<f64>,
    pub(crate) compared: u64,
}

/// Training state that is not the network itself.
#[derive(Debug)]
pub(crate) struct Counters {
    pub(crate) env_steps: u64,
    pub(crate) actors: BTreeMap<u16, ActorTrack>,
    /// Per task, the success of its last `success_window` episodes.
    pub(crate) windows: Vec<SuccessWindow>,
    window_len: usize,
    pub(crate) staleness: Staleness,
    /// Staleness over the last completed rate window (what status shows).
    staleness_shown: Staleness,
    pub(crate) rejected_batches: u64,
    pub(crate) failed_updates: u64,
    pub(crate) failed_in_a_row: u64,
    pub(crate) selected_samples: u64,
    updates_window: (Instant, u64),
    updates_per_second: f64,
    /// Time spent inside `Sac::update` in the current rate window.
    pub(crate) update_time: Duration,
    /// Updates per second of update time over the last window that had updates.
    busy_updates_per_second: f64,
    /// The learner's standalone rate, timed at start (0: not timed).
    pub(crate) standalone_updates_per_second: f64,
    /// Longest staging round in the current window, and in the last completed one.
    staging_max: Duration,
    staging_max_shown: Duration,
    /// Per task, what guidance did in the current rate window.
    pub(crate) guidance_window: Vec<GuidanceWindow>,
    /// Per task, the last completed window's guidance figures.
    guidance_shown: Vec<GuidanceShown>,
    pub(crate) guided_steps: u64,
    /// Loss stamps of everything received (status: `*_dropped`).
    pub(crate) inbound: crate::losses::Inbound,
    /// The checkpoint this learner resumed from and its update count.
    pub(crate) resumed: Option<(PathBuf, u64)>,
}

impl Counters {
    /// Zero counters for `num_tasks` tasks with success windows of `window_len` episodes.
    pub(crate) fn new(num_tasks: usize, window_len: usize, start: Instant) -> Self {
        let window_len = window_len.max(1);
        Self {
            env_steps: 0,
            actors: BTreeMap::new(),
            windows: vec![SuccessWindow::new(window_len); num_tasks],
            window_len,
            staleness: Staleness::default(),
            staleness_shown: Staleness::default(),
            rejected_batches: 0,
            failed_updates: 0,
            failed_in_a_row: 0,
            selected_samples: 0,
            updates_window: (start, 0),
            updates_per_second: 0.0,
            update_time: Duration::ZERO,
            busy_updates_per_second: 0.0,
            standalone_updates_per_second: 0.0,
            staging_max: Duration::ZERO,
            staging_max_shown: Duration::ZERO,
            guidance_window: vec![GuidanceWindow::default(); num_tasks],
            guidance_shown: vec![GuidanceShown::default(); num_tasks],
            guided_steps: 0,
            inbound: crate::losses::Inbound::default(),
            resumed: None,
        }
    }

    pub(crate) fn window_len(&self) -> usize {
        self.window_len
    }

    /// Records a finished episode's success in its task's window (episodes of unknown tasks
    /// are ignored).
    pub(crate) fn episode(&mut self, task: usize, success: bool) {
        if let Some(w) = self.windows.get_mut(task) {
            w.push(success);
        }
    }

    /// Records one staging round that took `took`.
    pub(crate) fn staging_round(&mut self, took: Duration) {
        self.staging_max = self.staging_max.max(took);
    }

    /// `busy / standalone` updates per second (0 when either is unknown).
    pub(crate) fn update_speed_ratio(&self) -> f64 {
        if self.standalone_updates_per_second > 0.0 && self.busy_updates_per_second > 0.0 {
            self.busy_updates_per_second / self.standalone_updates_per_second
        } else {
            0.0
        }
    }

    /// Counts the current rate window's updates from `updates` (a resumed learner's restored
    /// count): otherwise its first window would show every restored update as done in it.
    pub(crate) fn start_rates_at(&mut self, updates: u64) {
        self.updates_window.1 = updates;
    }

    /// Refreshes the windowed rates at `now` with the learner's `updates`; true when a rate
    /// window ([`RATE_WINDOW`]) closed.
    pub(crate) fn refresh_rates(&mut self, updates: u64, now: Instant) -> bool {
        let (t0, u0) = self.updates_window;
        let dt = (now - t0).as_secs_f64();
        let closed = now - t0 >= RATE_WINDOW;
        if closed {
            self.updates_per_second = (updates - u0) as f64 / dt;
            if updates > u0 && !self.update_time.is_zero() {
                self.busy_updates_per_second =
                    (updates - u0) as f64 / self.update_time.as_secs_f64();
            }
            self.update_time = Duration::ZERO;
            self.staging_max_shown = std::mem::take(&mut self.staging_max);
            self.updates_window = (now, updates);
            self.staleness_shown = std::mem::take(&mut self.staleness);
            for (shown, w) in self
                .guidance_shown
                .iter_mut()
                .zip(&mut self.guidance_window)
            {
                if w.steps > 0 {
                    *shown = w.shown();
                }
                *w = GuidanceWindow::default();
            }
        }
        for track in self.actors.values_mut() {
            match track.window {
                None => track.window = Some((now, track.env_steps)),
                Some((t0, s0)) if now - t0 >= RATE_WINDOW => {
                    track.steps_per_second =
                        (track.env_steps - s0) as f64 / (now - t0).as_secs_f64();
                    track.window = Some((now, track.env_steps));
                }
                Some(_) => {}
            }
        }
        closed
    }
}

/// What the status shows besides the counters.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Shown {
    pub(crate) policy_version: u64,
    pub(crate) checkpoint_failures: u64,
}

/// The `GetStatus` answer (without uptime) at `now`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn snapshot(
    run_id: &str,
    tasks: &[&str],
    c: &Counters,
    shown: Shown,
    sac: &Sac<f32>,
    replay: &MultiTaskReplay,
    capacity: usize,
    now: Instant,
) -> LearnerStatus {
    LearnerStatus {
        run_id: run_id.to_owned(),
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
            .map(|((task, w), g)| TaskSuccess {
                task: (*task).to_string(),
                success_rate: w.rate(),
                episodes: w.len() as u64,
                guidance_rate: g.rate,
                guidance_probability: g.probability,
                not_improving_rate: g.not_improving_rate,
                action_gap: g.action_gap,
                compared_steps: g.compared,
            })
            .collect(),
        staleness_mean: c.staleness_shown.mean(),
        staleness_max: c.staleness_shown.max,
        rejected_batches: c.rejected_batches + sac.rejected_batches(),
        policy_version: shown.policy_version,
        selected_samples: c.selected_samples,
        guided_steps: c.guided_steps,
        resumed_from: c
            .resumed
            .as_ref()
            .map(|(p, _)| p.display().to_string())
            .unwrap_or_default(),
        resumed_at_update: c.resumed.as_ref().map_or(0, |(_, u)| *u),
        checkpoint_failures: shown.checkpoint_failures,
        standalone_updates_per_second: c.standalone_updates_per_second,
        busy_updates_per_second: c.busy_updates_per_second,
        update_speed_ratio: c.update_speed_ratio(),
        staging_max_ms: c.staging_max_shown.as_secs_f64() * 1e3,
        ..LearnerStatus::default()
    }
}

/// Refreshes the shared status every [`STATUS_EVERY`], logs `progress` every 10 s and writes
/// the metrics log's window whenever a rate window closes.
#[derive(Debug)]
pub(crate) struct StatusBoard {
    last_status: Instant,
    last_log: Instant,
}

/// What one status refresh reads.
pub(crate) struct Sources<'a> {
    pub(crate) run_id: &'a str,
    pub(crate) algorithm: Algorithm,
    pub(crate) tasks: &'a [&'a str],
    pub(crate) sac: &'a Sac<f32>,
    pub(crate) replay: &'a MultiTaskReplay,
    pub(crate) capacity: usize,
    pub(crate) shown: Shown,
}

impl StatusBoard {
    pub(crate) fn new(start: Instant) -> Self {
        Self {
            last_status: start - STATUS_EVERY,
            last_log: start,
        }
    }

    /// Makes the next [`StatusBoard::tick`] refresh whatever the time since the last one (the
    /// final counters of a finished trainer).
    pub(crate) fn due_now(&mut self) {
        if let Some(past) = Instant::now().checked_sub(STATUS_EVERY) {
            self.last_status = past;
        }
    }

    /// Refreshes `shared`'s status when due.
    ///
    /// # Errors
    /// The metrics log cannot be written.
    pub(crate) fn tick(
        &mut self,
        src: Sources<'_>,
        c: &mut Counters,
        planner: Option<&mut PlannerTrainer>,
        metrics: &mut MetricsLog,
        shared: &Shared,
    ) -> anyhow::Result<()> {
        let now = Instant::now();
        if now - self.last_status < STATUS_EVERY {
            return Ok(());
        }
        self.last_status = now;
        let window_closed = c.refresh_rates(src.sac.updates(), now);
        let mut status = snapshot(
            src.run_id,
            src.tasks,
            c,
            src.shown,
            src.sac,
            src.replay,
            src.capacity,
            now,
        );
        c.inbound.fill(&mut status);
        status.algorithm = src.algorithm.as_str().to_string();
        let mut tep_after_success = 0;
        if let Some(p) = planner {
            tep_after_success = p.after_success;
            status.tep_after_success = p.after_success;
            if window_closed {
                p.roll_window();
            }
            status.tep_updates = p.updates();
            status.planner_version = p.published_version();
            status.tep_buffer_size = p.buffer_len() as u64;
            status.tep_buffer_capacity = p.buffer_capacity() as u64;
            status.tep_f_loss = p.shown_f_loss;
            status.tep_an_loss = p.shown_an_loss;
            status.tep_target_mean = p.shown_target_mean;
            status.tep_goal_distance_mean = p.shown_goal_distance_mean;
            status.planner = p.status(src.tasks);
        }
        if now - self.last_log >= LOG_EVERY {
            self.last_log = now;
            tracing::info!(
                updates = status.updates,
                updates_per_second = format!("{:.0}", status.updates_per_second),
                env_steps = status.env_steps_total,
                replay = status.replay_size,
                policy_version = status.policy_version,
                staleness_mean = format!("{:.0}", status.staleness_mean),
                tep_updates = status.tep_updates,
                tep_buffer = status.tep_buffer_size,
                tep_after_success,
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
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::staging::{ingest, tests::batch};
    use terl_transport::{ACTION_DIM, OBS_DIM};

    fn sac() -> Sac<f32> {
        Sac::new(terl_rl::SacConfig {
            obs_dim: OBS_DIM,
            act_dim: ACTION_DIM,
            num_tasks: 2,
            policy_hidden: vec![8],
            critic_hidden: vec![8],
            batch_size: 4,
            ..terl_rl::SacConfig::default()
        })
        .unwrap()
    }

    /// Success windows roll, rates come from completed windows only, and the snapshot shows
    /// what the counters, replay and published versions hold.
    #[test]
    fn the_snapshot_shows_windows_rates_and_counts() {
        let t0 = Instant::now();
        let mut c = Counters::new(2, 3, t0);
        for s in [true, true, false, false] {
            c.episode(0, s);
        }
        c.episode(1, true);
        c.episode(9, true);
        let mut replay = MultiTaskReplay::new(2, 100, OBS_DIM, ACTION_DIM);
        ingest(&batch(5, 1, 10, 0), 2, &mut replay, &mut c, 0);
        assert!(!c.refresh_rates(0, t0 + Duration::from_millis(500)));
        ingest(&batch(5, 0, 30, 0), 2, &mut replay, &mut c, 0);
        assert!(c.refresh_rates(40, t0 + Duration::from_millis(2500)));
        let shown = Shown {
            policy_version: 7,
            checkpoint_failures: 2,
        };
        let status = snapshot(
            "run",
            &["reach-v3", "push-v3"],
            &c,
            shown,
            &sac(),
            &replay,
            100,
            t0 + Duration::from_millis(2500),
        );
        assert_eq!(status.task_success[0].episodes, 3);
        assert!((status.task_success[0].success_rate - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(status.task_success[1].success_rate, 1.0);
        assert!((status.updates_per_second - 16.0).abs() < 1e-9);
        // Half of each batch is guided.
        assert_eq!(status.task_success[0].guidance_rate, 0.5);
        assert_eq!((status.env_steps_total, status.replay_size), (40, 40));
        assert_eq!(status.replay_capacity, 200);
        assert_eq!((status.policy_version, status.checkpoint_failures), (7, 2));
        assert_eq!(status.actors.len(), 1);
        assert_eq!(
            (status.actors[0].actor_id, status.actors[0].env_steps),
            (5, 40)
        );
        // The actor's rate: 30 steps over the 2 s since its window opened at 0.5 s.
        assert!((status.actors[0].env_steps_per_second - 15.0).abs() < 1e-9);
    }

    /// A resumed learner's first rate window counts from its restored update count.
    #[test]
    fn a_resumed_learners_first_rate_is_its_own() {
        let t0 = Instant::now();
        let mut c = Counters::new(1, 3, t0);
        c.start_rates_at(165_000);
        assert!(c.refresh_rates(165_040, t0 + Duration::from_secs(2)));
        assert!((c.updates_per_second - 20.0).abs() < 1e-9);
    }

    /// The busy rate counts only time inside updates; the ratio compares it with the standalone
    /// rate; the longest staging round of a window is shown after the window closes; a window
    /// without updates keeps the last busy rate.
    #[test]
    fn speed_is_updates_over_update_time_against_the_standalone_rate() {
        let t0 = Instant::now();
        let mut c = Counters::new(1, 3, t0);
        let replay = MultiTaskReplay::new(1, 10, OBS_DIM, ACTION_DIM);
        let shown = Shown {
            policy_version: 0,
            checkpoint_failures: 0,
        };
        let at = |c: &Counters, ms: u64| {
            snapshot(
                "run",
                &["reach-v3"],
                c,
                shown,
                &sac(),
                &replay,
                10,
                t0 + Duration::from_millis(ms),
            )
        };
        assert_eq!(at(&c, 0).update_speed_ratio, 0.0);
        c.standalone_updates_per_second = 40.0;
        // 10 updates in 2 s of wall time, of which 0.5 s were spent updating.
        c.update_time = Duration::from_millis(500);
        c.staging_round(Duration::from_micros(300));
        c.staging_round(Duration::from_micros(1200));
        c.staging_round(Duration::from_micros(100));
        assert_eq!(
            at(&c, 1000).staging_max_ms,
            0.0,
            "shown once the window closes"
        );
        assert!(c.refresh_rates(10, t0 + Duration::from_secs(2)));
        let s = at(&c, 2000);
        assert!((s.updates_per_second - 5.0).abs() < 1e-9);
        assert!((s.busy_updates_per_second - 20.0).abs() < 1e-9);
        assert!((s.update_speed_ratio - 0.5).abs() < 1e-9);
        assert!((s.standalone_updates_per_second - 40.0).abs() < 1e-9);
        assert!((s.staging_max_ms - 1.2).abs() < 1e-9);
        // A window without updates: the wall rate drops to 0, the busy rate stays.
        assert!(c.refresh_rates(10, t0 + Duration::from_secs(4)));
        let s = at(&c, 4000);
        assert_eq!(s.updates_per_second, 0.0);
        assert!((s.busy_updates_per_second - 20.0).abs() < 1e-9);
        assert_eq!(s.staging_max_ms, 0.0);
    }
}

#[cfg(test)]
mod guidance_window_tests {
    use super::*;
    use terl_transport::{flags, Transition};

    fn step(f: u8, p: f64, gap: f64) -> Transition {
        let mut t = Transition {
            flags: f,
            ..Transition::ZERO
        };
        t.set_guidance_probability(p);
        t.set_action_gap(gap);
        t
    }

    #[test]
    fn the_window_averages_each_figure_over_its_own_steps() {
        let mut w = GuidanceWindow::default();
        assert_eq!(
            w.shown(),
            GuidanceShown::default(),
            "nothing measured: all None"
        );
        // Two steps without a planner, three where it may act (σ^N 0.81), two compared (one of
        // them not improving and guided, ‖AN − π‖ 1.5), one more guided without comparison.
        w.record(&step(0, 0.0, 0.0));
        w.record(&step(0, 0.0, 0.0));
        let active = flags::GUIDANCE_ACTIVE;
        w.record(&step(active | flags::COMPARED, 0.81, 0.0));
        w.record(&step(
            active | flags::COMPARED | flags::NOT_IMPROVING | flags::GUIDED,
            0.81,
            1.5,
        ));
        w.record(&step(active | flags::GUIDED, 0.81, 0.5));
        let s = w.shown();
        assert!((s.rate - 2.0 / 5.0).abs() < 1e-12);
        assert!((s.probability.unwrap() - 0.81).abs() < 1e-4);
        assert_eq!((s.not_improving_rate, s.compared), (Some(0.5), 2));
        assert!((s.action_gap.unwrap() - 1.0).abs() < 1e-4);
    }
}
