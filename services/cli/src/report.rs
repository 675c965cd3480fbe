//! `terl report RUN_DIR...`: reports of one or more runs.
//!
//! Across runs ([`crate::results`]): `results.md` (Table I of final deterministic evaluation
//! success: IQM and mean over seeds × tasks with stratified bootstrap intervals, mean ± std
//! over seeds, next to the paper's numbers; the same with final = the mean of the last
//! `--last-evals` in-run evaluations; the probability of improvement between the algorithms of
//! an experiment; a per-task breakdown), `results.json`, and per experiment the evaluation
//! success and return curves, IQM with its interval (PNG and SVG).
//!
//! Per cluster run, from its MCAP logs (training episodes, not evaluations):
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
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;
use terl_rl::SuccessWindow;
use terl_wire::{EpisodeSummary, Metric};

#[derive(Debug, Args)]
pub struct ReportArgs {
    /// Run folders (`runs/<id>`): cluster runs (`episodes.mcap`, `metrics.mcap`, in-run
    /// evaluations) and `terl train` runs (`progress.jsonl`).
    #[arg(required = true, num_args = 1..)]
    pub run_dirs: Vec<PathBuf>,
    /// Where to write the cross-run results (`results.md`, `results.json`, charts) and the
    /// training reports of cluster runs (for several runs under `runs/<run folder name>/`;
    /// default: the run folder for one run, `./report` for several). A folder that cannot be
    /// read is noted and skipped.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Episodes per task in the rolling success window.
    #[arg(long, default_value_t = 50)]
    pub window: usize,
    /// The second definition of a run's final success: the mean of its last this many in-run
    /// evaluations (beside its final evaluation, `eval-final.json`).
    #[arg(long, default_value_t = crate::results::DEFAULT_LAST_EVALS)]
    pub last_evals: usize,
    /// Resamples of every stratified bootstrap interval (IQM, mean, probability of
    /// improvement, curves). The resampling stream has a fixed seed, so a report is the same
    /// on every run.
    #[arg(long, default_value_t = terl_stats::DEFAULT_REPS)]
    pub bootstrap_reps: usize,
    /// Run folders with checkpoints (e.g. one seed per algorithm) whose final policies are
    /// drawn into the qualitative figure at the end of `results.md`: per task, the frames of
    /// one deterministic episode of each run side by side (PNG in `<out>/frames/`). Needs
    /// headless OpenGL (./deploy/setup.sh installs it).
    #[arg(long, num_args = 1..)]
    pub frames_from: Vec<PathBuf>,
    /// The camera of the qualitative figure (a Meta-World camera: corner, corner2, corner3,
    /// corner4, topview, behindGripper, gripperPOV).
    #[arg(long, default_value = "corner")]
    pub frames_camera: String,
}

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

/// Most bootstrap resamples `--bootstrap-reps` accepts (each holds a row of means in memory).
pub const MAX_BOOTSTRAP_REPS: usize = 1_000_000;
/// Longest rolling window `--window` and `--last-evals` accept.
pub const MAX_WINDOW: usize = 1_000_000;

pub fn run(args: ReportArgs) -> Result<ExitCode> {
    anyhow::ensure!(
        (1..=MAX_WINDOW).contains(&args.window),
        "--window must be in 1..={MAX_WINDOW}"
    );
    anyhow::ensure!(
        (1..=MAX_WINDOW).contains(&args.last_evals),
        "--last-evals must be in 1..={MAX_WINDOW}"
    );
    anyhow::ensure!(
        (1..=MAX_BOOTSTRAP_REPS).contains(&args.bootstrap_reps),
        "--bootstrap-reps must be in 1..={MAX_BOOTSTRAP_REPS}"
    );
    // The qualitative figure's runs are checked before anything is written.
    let frames = if args.frames_from.is_empty() {
        None
    } else {
        Some(crate::frames::FrameSources::load(
            &args.frames_from,
            &args.frames_camera,
        )?)
    };
    let opts = crate::results::StatsOptions {
        last_evals: args.last_evals,
        bootstrap: terl_stats::Bootstrap::with_reps(args.bootstrap_reps),
    };
    let out = match (&args.out, args.run_dirs.as_slice()) {
        (Some(o), _) => o.clone(),
        (None, [one]) => one.clone(),
        (None, _) => PathBuf::from("report"),
    };
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut evaluated = Vec::new();
    let mut anything = false;
    let mut used_names: Vec<String> = Vec::new();
    let mut left_out: Vec<(PathBuf, String)> = Vec::new();
    for dir in crate::results::distinct_dirs(&args.run_dirs, "", "read once") {
        if !dir.is_dir() {
            eprintln!("note: {} is not a run folder; skipped", dir.display());
            continue;
        }
        if !terl_telemetry::existing_paths(dir, "episodes").is_empty() {
            // One run: its training report goes to --out (default: the run folder). Several:
            // each goes to a folder of its own under --out, never into the run folders.
            let run_out = if args.run_dirs.len() == 1 {
                out.clone()
            } else {
                let base = dir
                    .file_name()
                    .map_or_else(|| "run".to_string(), |n| n.to_string_lossy().into_owned());
                let mut name = base.clone();
                let mut k = 2;
                while used_names.contains(&name) {
                    name = format!("{base}-{k}");
                    k += 1;
                }
                used_names.push(name.clone());
                out.join("runs").join(name)
            };
            match training_report(dir, &run_out, args.window, args.run_dirs.len() == 1) {
                Ok(()) => anything = true,
                Err(e) => eprintln!("note: no training report for {}: {e:#}", dir.display()),
            }
        }
        match crate::results::load_run(dir) {
            Ok(r) => evaluated.push(r),
            Err(e) if e.is::<crate::results::NoEvaluations>() => {
                eprintln!("note: no evaluations used from {}: {e:#}", dir.display());
            }
            Err(e) => {
                eprintln!("error: evaluations of {} left out: {e:#}", dir.display());
                left_out.push((dir.clone(), format!("{e:#}")));
            }
        }
    }
    if !evaluated.is_empty() {
        let (mut md, mut files) = crate::results::write_results(&evaluated, &out, &opts)?;
        let md_path = out.join("results.md");
        if !left_out.is_empty() {
            md.push_str(&left_out_section(&left_out));
            std::fs::write(&md_path, &md)
                .with_context(|| format!("writing {}", md_path.display()))?;
        }
        if let Some(frames) = frames {
            eprintln!(
                "wrote {}; drawing the qualitative figure (one episode per task and run, \
                 a few seconds each)...",
                md_path.display()
            );
            let (section, pngs) = crate::frames::section(frames, &out)?;
            md.push_str(&section);
            std::fs::write(&md_path, &md)
                .with_context(|| format!("writing {}", md_path.display()))?;
            files.extend(pngs);
        }
        print!("{md}");
        for f in files {
            eprintln!("wrote {}", f.display());
        }
        anything = true;
    }
    if !left_out.is_empty() {
        // The report covers the rest, but a run lost from a comparison must not pass unseen.
        eprintln!(
            "error: {} run folder(s) left out of the report, their evaluations unreadable: {}",
            left_out.len(),
            left_out
                .iter()
                .map(|(d, _)| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
        return Ok(ExitCode::FAILURE);
    }
    anyhow::ensure!(
        anything,
        "nothing to report: no episodes.mcap and no evaluations in {:?}",
        args.run_dirs
    );
    Ok(ExitCode::SUCCESS)
}

/// The `results.md` section that names the run folders whose evaluations could not be used.
fn left_out_section(left_out: &[(PathBuf, String)]) -> String {
    let mut md = String::from(
        "\n## Run folders left out\n\nTheir evaluations exist but could not be used, so the \
         tables above do not include them (`terl report` exits with status 1):\n\n",
    );
    for (dir, why) in left_out {
        let _ = writeln!(md, "- `{}`: {}", dir.display(), why.replace('\n', " "));
    }
    md
}

/// Every record of the run's `<kind>.mcap` log and its restarted segments (`<kind>.2.mcap`,
/// …), in order, and the segments read only in part (a stopped writer, a cut or damage), each
/// with the reason and the number of records kept from it.
pub(crate) fn read_run_log<R: terl_telemetry::LogRecord>(
    run_dir: &Path,
    kind: &str,
) -> Result<(Vec<R>, Vec<CutLog>)> {
    let (mut records, mut cut) = (Vec::new(), Vec::new());
    for f in terl_telemetry::existing_paths(run_dir, kind) {
        let log = terl_telemetry::read_log::<R>(&f)
            .with_context(|| format!("reading {}", f.display()))?;
        if let Some(reason) = log.truncation {
            cut.push(CutLog {
                path: f,
                reason,
                kept: log.records.len(),
            });
        }
        records.extend(log.records);
    }
    Ok((records, cut))
}

/// A log segment read only in part.
#[derive(Debug)]
pub(crate) struct CutLog {
    pub(crate) path: PathBuf,
    /// Why reading stopped (from the reader).
    pub(crate) reason: String,
    /// Records kept from before that point.
    pub(crate) kept: usize,
}

impl std::fmt::Display for CutLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "note: {} is read only in part: {}; using the {} records before that point",
            self.path.display(),
            self.reason,
            self.kept
        )
    }
}

/// `report.md` and `learning-curves.svg` of one cluster run's training episodes.
fn training_report(run_dir: &Path, out: &Path, window: usize, print: bool) -> Result<()> {
    let (episodes, cut_episodes) = read_run_log::<EpisodeSummary>(run_dir, "episodes")?;
    let (metrics, cut_metrics) = read_run_log::<Metric>(run_dir, "metrics")?;
    let rows = task_rows(&episodes, window);
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    // A cut eval.mcap is noted by results::load_run, which reads it for every run folder.
    let (evals, _) = read_run_log::<terl_wire::EvalResult>(run_dir, "eval")?;
    for c in cut_episodes.iter().chain(&cut_metrics) {
        eprintln!("{c}");
    }
    let mut md = markdown(run_dir, &rows, window, &metrics);
    md.push_str(&eval_markdown(&evals));
    let md_path = out.join("report.md");
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    let svg_path = out.join("learning-curves.svg");
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
