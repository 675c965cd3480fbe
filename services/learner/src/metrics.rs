//! The learner's metrics log, `runs/<id>/metrics.mcap` (`terl.v1.Metric` on `/metrics`): one
//! sample of every metric per status window, flushed at once so a killed learner keeps its
//! history; the same samples as TensorBoard scalars keyed by env steps
//! (`runs/<id>/events.out.tfevents.*.learner`: `tensorboard --logdir runs` shows live runs).
//! cleanrl-style names: `charts/…`, `losses/…`, `replay/…`, `tep/…`, `success_rate/<task>`, `guidance/rate/<task>`, and what senders report they could not
//! deliver (cumulative counts, see `crate::losses`): `transport/transition_batches_dropped`,
//! `transport/transitions_dropped`, `transport/episodes_dropped`,
//! `transport/selected_samples_dropped`, and per actor
//! `transport/transitions_dropped/actor-<id>` and `transport/episodes_dropped/actor-<id>`.
//! The machine: `charts/update_share` (share of the window's wall time spent in updates: near 1
//! the run is learner-bound), `process/cpu_cores` (the learner process's CPU use over the
//! window, in cores) and `process/rss_mb` (its resident memory, MB).
//! TERL runs add `tep/target_mean` (mean
//! target of the hindsight term), `tep/goal_distance_mean` (mean `F(s_t, s', a_t)`), F's three
//! loss terms (`tep/step_loss`, `tep/goal_loss`, `tep/symmetry_loss`), `tep/an_bc_loss`,
//! `tep/gap_mean` (mean hindsight gap), and per task `tep/transitions/<task>` (TEP buffer),
//! `tep/held_out_spearman/<task>` (the planner check's ρ), `guidance/validated/<task>` (0/1:
//! the gate; its step is the gate-open event), and, per task in windows where they were
//! measured, `guidance/probability/<task>` (mean σ^N of Eq. 15 where the planner could act),
//! `guidance/not_improving_rate/<task>` (share of decisions with `f_t ≥ f_{t−1}`) and
//! `guidance/action_gap/<task>` (mean ‖AN − π‖ over guided steps).

use std::path::Path;

use anyhow::Context;
use terl_rl::UpdateStats;
use terl_telemetry::{EventWriter, MetricsWriter};
use terl_wire::{LearnerStatus, Metric};

/// SAC losses summed over the current window.
#[derive(Debug, Default)]
struct LossSums {
    qf: f64,
    actor: f64,
    alpha: f64,
    n: u64,
}

pub(crate) struct MetricsLog {
    writer: MetricsWriter,
    tensorboard: EventWriter,
    sums: LossSums,
    /// The learner process's CPU counters at the previous window (for `process/cpu_cores`).
    usage: Option<terl_runtime::process::Usage>,
}

impl MetricsLog {
    pub(crate) fn create(run_dir: &Path) -> anyhow::Result<Self> {
        let path = terl_telemetry::fresh_path(run_dir, "metrics");
        let writer = MetricsWriter::create(&path)
            .with_context(|| format!("cannot create the metrics log {}", path.display()))?;
        let tensorboard = EventWriter::create(run_dir, "learner").with_context(|| {
            format!(
                "cannot create the TensorBoard event file in {}",
                run_dir.display()
            )
        })?;
        Ok(Self {
            writer,
            tensorboard,
            sums: LossSums::default(),
            usage: terl_runtime::process::usage(None).ok(),
        })
    }

    pub(crate) fn record_update(&mut self, s: &UpdateStats) {
        self.sums.qf += 0.5 * (s.qf1_loss + s.qf2_loss);
        self.sums.actor += s.actor_loss;
        self.sums.alpha += s.alpha_mean;
        self.sums.n += 1;
    }

    /// Writes one sample of every metric in `status` (at learner step `status.updates`).
    #[allow(clippy::too_many_lines)] // one metric after another, in the log's order
    pub(crate) fn write_window(&mut self, status: &LearnerStatus) -> anyhow::Result<()> {
        let now = terl_telemetry::unix_nanos();
        let step = status.updates;
        let mut out: Vec<(String, f64)> = vec![
            (
                "charts/updates_per_second".into(),
                status.updates_per_second,
            ),
            (
                "charts/busy_updates_per_second".into(),
                status.busy_updates_per_second,
            ),
            (
                "charts/update_speed_ratio".into(),
                status.update_speed_ratio,
            ),
            ("charts/staging_max_ms".into(), status.staging_max_ms),
            (
                "charts/env_steps_per_second".into(),
                status.actors.iter().map(|a| a.env_steps_per_second).sum(),
            ),
            ("charts/env_steps".into(), status.env_steps_total as f64),
            ("replay/size".into(), status.replay_size as f64),
            ("replay/staleness_mean".into(), status.staleness_mean),
            (
                "replay/rejected_batches".into(),
                status.rejected_batches as f64,
            ),
        ];
        out.extend([
            (
                "transport/transition_batches_dropped".into(),
                status.transition_batches_dropped as f64,
            ),
            (
                "transport/transitions_dropped".into(),
                status.transitions_dropped as f64,
            ),
            (
                "transport/episodes_dropped".into(),
                status.episodes_dropped as f64,
            ),
            (
                "transport/selected_samples_dropped".into(),
                status.selected_samples_dropped as f64,
            ),
        ]);
        for a in &status.actors {
            out.push((
                format!("transport/transitions_dropped/actor-{}", a.actor_id),
                a.transitions_dropped as f64,
            ));
            out.push((
                format!("transport/episodes_dropped/actor-{}", a.actor_id),
                a.episodes_dropped as f64,
            ));
        }
        if status.busy_updates_per_second > 0.0 {
            out.push((
                "charts/update_share".into(),
                (status.updates_per_second / status.busy_updates_per_second).min(1.0),
            ));
        }
        if let Ok(now) = terl_runtime::process::usage(None) {
            if let Some(before) = &self.usage {
                out.push((
                    "process/cpu_cores".into(),
                    terl_runtime::process::cores_between(before, &now),
                ));
            }
            out.push(("process/rss_mb".into(), now.rss_bytes as f64 / 1e6));
            self.usage = Some(now);
        }
        let s = std::mem::take(&mut self.sums);
        if s.n > 0 {
            let n = s.n as f64;
            out.push(("losses/qf_loss".into(), s.qf / n));
            out.push(("losses/actor_loss".into(), s.actor / n));
            out.push(("losses/alpha".into(), s.alpha / n));
        }
        for t in &status.task_success {
            out.push((format!("success_rate/{}", t.task), t.success_rate));
        }
        if status.algorithm == "terl" {
            out.extend([
                ("tep/updates".into(), status.tep_updates as f64),
                ("tep/buffer_size".into(), status.tep_buffer_size as f64),
                ("tep/f_loss".into(), status.tep_f_loss),
                ("tep/an_loss".into(), status.tep_an_loss),
                ("tep/target_mean".into(), status.tep_target_mean),
                (
                    "tep/goal_distance_mean".into(),
                    status.tep_goal_distance_mean,
                ),
                (
                    "tep/selected_samples".into(),
                    status.selected_samples as f64,
                ),
                ("guidance/guided_steps".into(), status.guided_steps as f64),
            ]);
            for t in &status.task_success {
                out.push((format!("guidance/rate/{}", t.task), t.guidance_rate));
                let optional = [
                    ("guidance/probability", t.guidance_probability),
                    ("guidance/not_improving_rate", t.not_improving_rate),
                    ("guidance/action_gap", t.action_gap),
                ];
                for (name, value) in optional {
                    if let Some(v) = value {
                        out.push((format!("{name}/{}", t.task), v));
                    }
                }
            }
            let p = &status.planner;
            out.extend([
                ("tep/step_loss".into(), p.step_loss),
                ("tep/goal_loss".into(), p.goal_loss),
                ("tep/symmetry_loss".into(), p.symmetry_loss),
                ("tep/an_bc_loss".into(), p.an_bc_loss),
                ("tep/gap_mean".into(), p.gap_mean),
            ]);
            for t in &p.tasks {
                out.push((
                    format!("tep/transitions/{}", t.task),
                    t.tep_transitions as f64,
                ));
                out.push((
                    format!("guidance/validated/{}", t.task),
                    f64::from(u8::from(t.validated)),
                ));
                if let Some(r) = t.spearman {
                    out.push((format!("tep/held_out_spearman/{}", t.task), r));
                }
            }
        }
        self.tensorboard.scalars(
            status.env_steps_total,
            now as f64 / 1e9,
            out.iter().map(|(name, value)| (name.as_str(), *value)),
        )?;
        for (name, value) in out {
            let m = Metric {
                name,
                value,
                step,
                unix_time_nanos: now,
            };
            self.writer.write(&m, now)?;
        }
        self.writer.flush()?;
        Ok(())
    }

    pub(crate) fn finish(self) -> anyhow::Result<u64> {
        Ok(self.writer.finish()?)
    }
}
