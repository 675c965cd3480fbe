//! `terl report RUN_DIR...`: reports of one or more runs.
//!
//! Across runs: `results.md` (Table I of final deterministic evaluation success: IQM and mean
//! over seeds × tasks with stratified bootstrap intervals, mean ± std over seeds, next to the
//! paper's numbers; the same with final = the mean of the last `--last-evals` in-run
//! evaluations; the probability of improvement between the algorithms of an experiment; a
//! per-task breakdown), `results.json`, and per experiment the evaluation success and return
//! curves, IQM with its interval (PNG and SVG); with `--frames-from`, the qualitative figure.
//! Per cluster run: its training report ([`training`]).
//!
//! The parts, each importing only those listed before it:
//! - [`runs`]: a run folder as evaluation results (reading and checking its files);
//! - [`stats`]: groups, final success, IQM, means and probabilities of improvement;
//! - [`charts`]: learning curves with their intervals (plotters, PNG and SVG);
//! - [`tables`]: `results.md`, `results.json` and the charts of a set of runs;
//! - [`training`]: one cluster run's training report (`report.md`, `learning-curves.svg`);
//! - [`frames`]: the qualitative figure (rendered episodes of final policies);
//! - this module: the command.

pub mod charts;
pub mod frames;
pub mod runs;
pub mod stats;
pub mod tables;
pub mod training;

#[cfg(test)]
mod tests;

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

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
    #[arg(long, value_parser = terl_runtime::flags::count::<usize>(MAX_WINDOW as u64), default_value_t = 50)]
    pub window: usize,
    /// The second definition of a run's final success: the mean of its last this many in-run
    /// evaluations (beside its final evaluation, `eval-final.json`).
    #[arg(long, value_parser = terl_runtime::flags::count::<usize>(MAX_WINDOW as u64), default_value_t = stats::DEFAULT_LAST_EVALS)]
    pub last_evals: usize,
    /// Resamples of every stratified bootstrap interval (IQM, mean, probability of
    /// improvement, curves). The resampling stream has a fixed seed, so a report is the same
    /// on every run.
    #[arg(long, value_parser = terl_runtime::flags::count::<usize>(MAX_BOOTSTRAP_REPS as u64), default_value_t = terl_stats::DEFAULT_REPS)]
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

/// Most bootstrap resamples `--bootstrap-reps` accepts (each holds a row of means in memory).
pub const MAX_BOOTSTRAP_REPS: usize = 1_000_000;
/// Longest rolling window `--window` and `--last-evals` accept.
pub const MAX_WINDOW: usize = 1_000_000;

/// Refuses option values outside their bounds before anything is read or written.
fn check_bounds(args: &ReportArgs) -> Result<()> {
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
    Ok(())
}

pub fn run(args: ReportArgs) -> Result<ExitCode> {
    check_bounds(&args)?;
    // The qualitative figure's runs are checked before anything is written.
    let frames = if args.frames_from.is_empty() {
        None
    } else {
        Some(frames::FrameSources::load(
            &args.frames_from,
            &args.frames_camera,
        )?)
    };
    let opts = stats::StatsOptions {
        last_evals: args.last_evals,
        bootstrap: terl_stats::Bootstrap::with_reps(args.bootstrap_reps),
    };
    let out = out_dir(&args)?;
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    // Two reports into one folder would overwrite each other's tables and charts.
    let _lock = if args.run_dirs.len() > 1 {
        Some(crate::folder_lock::lock_dir(&out, "terl report")?)
    } else {
        None
    };
    let mut evaluated = Vec::new();
    let mut anything = false;
    let mut used_names: Vec<String> = Vec::new();
    let mut left_out: Vec<(PathBuf, String)> = Vec::new();
    // Every file this report wrote or tried to write (a failed write leaves nothing stale).
    let mut written: Vec<PathBuf> = Vec::new();
    for dir in runs::distinct_dirs(&args.run_dirs, "", "read once") {
        if !dir.is_dir() {
            eprintln!("note: {} is not a run folder; skipped", dir.display());
            continue;
        }
        if terl_telemetry::existing_paths(dir, "episodes").is_empty() {
            // Without a first segment no training log is read: the later ones are named.
            for stem in ["episodes", "metrics"] {
                for p in terl_telemetry::unread_segments(dir, stem) {
                    eprintln!("{}", terl_telemetry::unread_segment_note(&p));
                }
            }
        } else {
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
            written.extend(training::FILES.iter().map(|f| run_out.join(f)));
            match training::training_report(dir, &run_out, args.window, args.run_dirs.len() == 1) {
                Ok(()) => anything = true,
                Err(e) => eprintln!("note: no training report for {}: {e:#}", dir.display()),
            }
        }
        match runs::load_run(dir) {
            Ok(r) => evaluated.push(r),
            Err(e) if e.is::<runs::NoEvaluations>() => {
                eprintln!("note: no evaluations used from {}: {e:#}", dir.display());
            }
            Err(e) => {
                eprintln!("error: evaluations of {} left out: {e:#}", dir.display());
                left_out.push((dir.clone(), format!("{e:#}")));
            }
        }
    }
    if !evaluated.is_empty() {
        let (mut md, mut files) = tables::write_results(&evaluated, &out, &opts)?;
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
            let (section, pngs) = frames::section(frames, &out)?;
            md.push_str(&section);
            std::fs::write(&md_path, &md)
                .with_context(|| format!("writing {}", md_path.display()))?;
            files.extend(pngs);
        }
        print!("{md}");
        for f in &files {
            eprintln!("wrote {}", f.display());
        }
        written.extend(files);
        anything = true;
    }
    if args.run_dirs.len() > 1 {
        note_stale_outputs(&out, &written);
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

/// Names on stderr the files of an earlier report into `out` that this one did not rewrite
/// ([`stale_outputs`]).
fn note_stale_outputs(out: &std::path::Path, written: &[PathBuf]) {
    const LISTED: usize = 20;
    let stale = stale_outputs(out, written);
    for path in stale.iter().take(LISTED) {
        eprintln!(
            "note: {} is from an earlier report into {} (this one did not write it); use a \
             fresh --out to keep only this report's files",
            path.display(),
            out.display()
        );
    }
    if stale.len() > LISTED {
        eprintln!(
            "note: and {} more files of earlier reports in {}",
            stale.len() - LISTED,
            out.display()
        );
    }
}

/// Files under a multi-run `--out` named as this command names its outputs (`results.*`, the
/// `*-eval-success`/`*-eval-return` charts, `runs/*/report.md` and `learning-curves.svg`,
/// `frames/*.png`) that are not in `written`: left by an earlier report of other runs. Only
/// named, never removed (they may be all that is left of that report).
fn stale_outputs(out: &std::path::Path, written: &[PathBuf]) -> Vec<PathBuf> {
    let files_in = |dir: PathBuf| -> Vec<PathBuf> {
        std::fs::read_dir(dir).map_or_else(
            |_| Vec::new(),
            |rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect(),
        )
    };
    let name_of = |p: &PathBuf| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let mut ours: Vec<PathBuf> = files_in(out.to_path_buf())
        .into_iter()
        .filter(|p| {
            let n = name_of(p);
            n == "results.md"
                || n == "results.json"
                || [".svg", ".png"].iter().any(|ext| {
                    n.strip_suffix(ext).is_some_and(|s| {
                        s.ends_with("-eval-success") || s.ends_with("-eval-return")
                    })
                })
        })
        .collect();
    for run in files_in(out.join("runs")) {
        // A run folder itself (`--out .` beside `runs/`): its report.md is that run's own.
        if ["config.toml", "cluster.txt", "episodes.mcap"]
            .iter()
            .any(|f| std::fs::symlink_metadata(run.join(f)).is_ok())
        {
            continue;
        }
        ours.extend(
            files_in(run)
                .into_iter()
                .filter(|p| training::FILES.contains(&name_of(p).as_str())),
        );
    }
    ours.extend(
        files_in(out.join("frames"))
            .into_iter()
            .filter(|p| name_of(p).ends_with(".png")),
    );
    ours.retain(|p| p.is_file() && !written.contains(p));
    ours.sort();
    ours
}

/// `--out`, else the run folder for one run (which must exist: a mistyped one is not created),
/// else `./report`.
fn out_dir(args: &ReportArgs) -> Result<PathBuf> {
    Ok(match (&args.out, args.run_dirs.as_slice()) {
        (Some(o), _) => o.clone(),
        (None, [one]) => {
            // The run folder itself: a mistyped one must not be created.
            anyhow::ensure!(
                one.is_dir(),
                "{} is not a folder (give run folders, runs/<id>)",
                one.display()
            );
            one.clone()
        }
        (None, _) => PathBuf::from("report"),
    })
}
