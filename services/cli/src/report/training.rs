//! The training report of one cluster run, from its MCAP logs (training episodes, not
//! evaluations):
//! - `report.md`: per task, the training success rate over the last `--window` episodes and
//!   over all episodes, mean return and length, guided-step share (from the selector's
//!   `episodes.mcap`), plus the run's final learner metrics (from `metrics.mcap`) and every
//!   in-run evaluation of the deterministic policy (from the selector's `eval.mcap`);
//! - `learning-curves.svg`: per task, the success rate over a rolling window of episodes against
//!   the episodes finished, and the mean over tasks.
//!
//! Restarted services write `episodes.2.mcap`, `metrics.2.mcap`, …: all files of a kind are
//! read, in order. Files whose writer was killed are read up to their last flush.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};
use terl_rl::SuccessWindow;
use terl_telemetry::read_run_log;
use terl_wire::{EpisodeSummary, Metric};

/// Per-task statistics of the episode log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TaskRow {
    pub task: String,
    pub episodes: usize,
    /// Success rate over the last `window` episodes.
    pub recent_success: f64,
    pub overall_success: f64,
    pub mean_return: f64,
    pub mean_length: f64,
    /// Guided steps / steps.
    pub guided_share: f64,
    /// `(episodes finished, rolling success rate)` after each episode.
    pub curve: Vec<(usize, f64)>,
}

/// Groups episodes by task (in first-seen order) and computes the table and curves.
pub fn task_rows(episodes: &[EpisodeSummary], window: usize) -> Vec<TaskRow> {
    let window = window.max(1);
    let mut by_task: BTreeMap<&str, Vec<&EpisodeSummary>> = BTreeMap::new();
    let mut order: Vec<&str> = Vec::new();
    for e in episodes {
        by_task
            .entry(e.task.as_str())
            .or_insert_with(|| {
                order.push(e.task.as_str());
                Vec::new()
            })
            .push(e);
    }
    order
        .into_iter()
        .map(|task| {
            let eps = &by_task[task];
            let n = eps.len();
            let ok: Vec<f64> = eps.iter().map(|e| f64::from(u8::from(e.success))).collect();
            let mut recent = SuccessWindow::new(window);
            let curve = eps
                .iter()
                .enumerate()
                .map(|(i, e)| {
                    recent.push(e.success);
                    (i + 1, recent.rate())
                })
                .collect::<Vec<_>>();
            let steps: u64 = eps.iter().map(|e| u64::from(e.length)).sum();
            let guided: u64 = eps.iter().map(|e| u64::from(e.guided_steps)).sum();
            TaskRow {
                task: task.to_string(),
                episodes: n,
                recent_success: curve.last().map_or(0.0, |c| c.1),
                overall_success: ok.iter().sum::<f64>() / n as f64,
                mean_return: eps.iter().map(|e| e.episode_return).sum::<f64>() / n as f64,
                mean_length: steps as f64 / n as f64,
                guided_share: if steps > 0 {
                    guided as f64 / steps as f64
                } else {
                    0.0
                },
                curve,
            }
        })
        .collect()
}

/// The last value of every metric (by log order).
fn final_metrics(metrics: &[Metric]) -> BTreeMap<String, (f64, u64)> {
    let mut out = BTreeMap::new();
    for m in metrics {
        out.insert(m.name.clone(), (m.value, m.step));
    }
    out
}

fn markdown(run_dir: &Path, rows: &[TaskRow], window: usize, metrics: &[Metric]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Run report: {}\n", run_dir.display());
    let _ = writeln!(
        s,
        "Training episodes from `episodes.mcap`; success over the last {window} episodes of each task.\n"
    );
    let _ = writeln!(
        s,
        "| task | episodes | success (last {window}) | success (all) | mean return | mean length | guided steps |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {} | {:.1} % | {:.1} % | {:.1} | {:.0} | {:.1} % |",
            r.task,
            r.episodes,
            100.0 * r.recent_success,
            100.0 * r.overall_success,
            r.mean_return,
            r.mean_length,
            100.0 * r.guided_share
        );
    }
    if !rows.is_empty() {
        let mean = rows.iter().map(|r| r.recent_success).sum::<f64>() / rows.len() as f64;
        let _ = writeln!(
            s,
            "| **mean over tasks** | {} | **{:.1} %** | | | | |",
            rows.iter().map(|r| r.episodes).sum::<usize>(),
            100.0 * mean
        );
    }
    let last = final_metrics(metrics);
    if !last.is_empty() {
        let _ = writeln!(s, "\n## Final learner metrics (`metrics.mcap`)\n");
        let _ = writeln!(s, "| metric | value | at update |");
        let _ = writeln!(s, "|---|---|---|");
        for (name, (value, step)) in &last {
            let _ = writeln!(s, "| {name} | {value:.4} | {step} |");
        }
    }
    let _ = writeln!(s, "\nLearning curves: `learning-curves.svg`.");
    s
}

/// A plain SVG line chart: rolling success rate per task against episodes of that task.
pub fn svg(rows: &[TaskRow], window: usize) -> String {
    const W: f64 = 760.0;
    const H: f64 = 420.0;
    const L: f64 = 60.0;
    const R: f64 = 200.0;
    const T: f64 = 40.0;
    const B: f64 = 50.0;
    let colors = [
        "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
        "#bcbd22", "#17becf",
    ];
    let max_x = rows.iter().map(|r| r.episodes).max().unwrap_or(1).max(1) as f64;
    let x = |e: f64| L + (W - L - R) * e / max_x;
    let y = |v: f64| T + (H - T - B) * (1.0 - v);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="{W}" height="{H}" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="{L}" y="22" font-size="14">Training success rate (rolling {window} episodes per task)</text>"#
    );
    for k in 0..=4 {
        let v = f64::from(k) / 4.0;
        let _ = writeln!(
            s,
            r##"<line x1="{L}" y1="{y:.1}" x2="{x2:.1}" y2="{y:.1}" stroke="#ddd"/><text x="{tx:.1}" y="{ty:.1}" text-anchor="end">{p:.0} %</text>"##,
            y = y(v),
            x2 = W - R,
            tx = L - 6.0,
            ty = y(v) + 4.0,
            p = 100.0 * v
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="{cx:.1}" y="{by:.1}" text-anchor="middle">episodes of the task (max {max_x:.0})</text>"#,
        cx = (L + W - R) / 2.0,
        by = H - 15.0
    );
    for (i, r) in rows.iter().enumerate() {
        let color = colors[i % colors.len()];
        let points: Vec<String> = r
            .curve
            .iter()
            .map(|&(e, v)| format!("{:.1},{:.1}", x(e as f64), y(v)))
            .collect();
        let _ = writeln!(
            s,
            r#"<polyline fill="none" stroke="{color}" stroke-width="1.5" points="{}"><title>{}</title></polyline>"#,
            points.join(" "),
            r.task
        );
        let ly = T + 16.0 * i as f64;
        let _ = writeln!(
            s,
            r#"<rect x="{lx:.1}" y="{ry:.1}" width="12" height="3" fill="{color}"/><text x="{tx:.1}" y="{ty:.1}">{} ({:.0} %)</text>"#,
            r.task,
            100.0 * r.recent_success,
            lx = W - R + 12.0,
            ry = ly - 4.0,
            tx = W - R + 30.0,
            ty = ly
        );
    }
    s.push_str("</svg>\n");
    s
}

/// The in-run evaluations (`eval.mcap`): one row per evaluation, success in percent (empty
/// when the run logged none).
fn eval_markdown(evals: &[terl_wire::EvalResult]) -> String {
    let Some(first) = evals.first() else {
        return String::new();
    };
    let mut s = String::from(
        "\n## In-run evaluation (`eval.mcap`: deterministic policy on goal variations)\n\n",
    );
    let tasks: Vec<&str> = first.tasks.iter().map(|t| t.task.as_str()).collect();
    let _ = writeln!(
        s,
        "| env steps | policy version | episodes/task | mean success | {} |",
        tasks.join(" | ")
    );
    let _ = writeln!(s, "|---|---|---|---|{}", "---|".repeat(tasks.len()));
    for e in evals {
        let per: Vec<String> = e
            .tasks
            .iter()
            .map(|t| format!("{:.0}%", 100.0 * t.success_rate))
            .collect();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {:.1}% | {} |",
            e.env_steps,
            e.policy_version,
            e.episodes_per_task,
            100.0 * e.mean_success_rate,
            per.join(" | ")
        );
    }
    s
}

/// The files [`training_report`] writes into its folder.
pub(super) const FILES: [&str; 2] = ["report.md", "learning-curves.svg"];

/// `report.md` and `learning-curves.svg` of one cluster run's training episodes.
pub(super) fn training_report(
    run_dir: &Path,
    out: &Path,
    window: usize,
    print: bool,
) -> Result<()> {
    let episodes = read_run_log::<EpisodeSummary>(run_dir, "episodes")?;
    let metrics = read_run_log::<Metric>(run_dir, "metrics")?;
    let rows = task_rows(&episodes.records, window);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    // A cut eval.mcap is noted by runs::load_run, which reads it for every run folder.
    let evals = read_run_log::<terl_wire::EvalResult>(run_dir, "eval")?.records;
    for note in episodes.notes().into_iter().chain(metrics.notes()) {
        eprintln!("{note}");
    }
    let mut md = markdown(run_dir, &rows, window, &metrics.records);
    md.push_str(&eval_markdown(&evals));
    let md_path = out.join(FILES[0]);
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    let svg_path = out.join(FILES[1]);
    std::fs::write(&svg_path, svg(&rows, window))
        .with_context(|| format!("writing {}", svg_path.display()))?;
    if print {
        print!("{md}");
    }
    eprintln!("wrote {} and {}", md_path.display(), svg_path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ep(task: &str, success: bool, ret: f64, guided: u32) -> EpisodeSummary {
        EpisodeSummary {
            task: task.into(),
            actor_id: 0,
            episode_index: 0,
            episode_return: ret,
            success,
            length: 500,
            policy_version: 1,
            guided_steps: guided,
            missed_before: 0,
        }
    }

    #[test]
    fn table_and_curves_by_hand() {
        let eps = vec![
            ep("b", false, 1.0, 0),
            ep("a", true, 2.0, 50),
            ep("b", true, 3.0, 0),
            ep("b", true, 5.0, 100),
            ep("a", false, 4.0, 0),
        ];
        let rows = task_rows(&eps, 2);
        assert_eq!(rows.len(), 2);
        let b = &rows[0];
        assert_eq!((b.task.as_str(), b.episodes), ("b", 3));
        assert_eq!(b.curve, vec![(1, 0.0), (2, 0.5), (3, 1.0)]);
        assert_eq!(b.recent_success, 1.0);
        assert!((b.overall_success - 2.0 / 3.0).abs() < 1e-12);
        assert!((b.mean_return - 3.0).abs() < 1e-12);
        assert!((b.guided_share - 100.0 / 1500.0).abs() < 1e-12);
        let a = &rows[1];
        assert_eq!(a.curve, vec![(1, 1.0), (2, 0.5)]);
        let chart = svg(&rows, 2);
        assert_eq!(chart.matches("<polyline").count(), 2);
        assert!(chart.starts_with("<svg") && chart.trim_end().ends_with("</svg>"));
        let md = markdown(Path::new("runs/x"), &rows, 2, &[]);
        assert!(
            md.contains("| b | 3 | 100.0 % | 66.7 % | 3.0 | 500 | 6.7 % |"),
            "{md}"
        );
        assert!(md.contains("**75.0 %**"), "{md}");
    }
}
