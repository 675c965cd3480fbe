//! The qualitative figure of `terl report --frames-from RUN...` (the paper's Fig. 5): per task,
//! one deterministic episode of each given run's final policy (evaluation episode 0: goal
//! variation 0 of the run's variation seed), three frames per run side by side — after the
//! reset, the first success (else the frame nearest the goal: the highest reward among every
//! 10th step), the last step — one row per run, drawn offscreen by MuJoCo
//! ([`crate::render::record_episode`]). The PNGs go to `<out>/frames/`, the section to the end
//! of `results.md`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use terl_sim::metaworld::goal_variations;
use terl_sim::render::Renderer;
use terl_sim::Env;

use super::runs::{load_run, RunEval};
use super::tables::file_stem;
use crate::eval::PolicyAndTasks;
use crate::render::{record_episode, write_grid, Shot};

/// Side of one frame of the figure, pixels.
const SIDE: u32 = 240;
/// Candidates for "nearest the goal": every this many steps.
const EVERY: u32 = 10;

struct Source {
    run: RunEval,
    loaded: PolicyAndTasks,
    seed: u64,
}

/// The runs of the figure, loaded and checked before a report writes anything.
pub(crate) struct FrameSources {
    by_experiment: BTreeMap<String, Vec<Source>>,
    camera: String,
}

impl FrameSources {
    /// Loads every run (its evaluations' metadata and its newest checkpoint; a folder given
    /// twice counts once) and checks the camera against the scenes and that offscreen OpenGL
    /// works.
    pub(crate) fn load(runs: &[PathBuf], camera: &str) -> Result<Self> {
        crate::font::register_font()?;
        let mut by_experiment: BTreeMap<String, Vec<Source>> = BTreeMap::new();
        for dir in super::runs::distinct_dirs(runs, "--frames-from ", "drawn once") {
            let run = load_run(dir)
                .with_context(|| format!("--frames-from {}: not a run folder", dir.display()))?;
            let loaded = PolicyAndTasks::load(dir, None, None, None).with_context(|| {
                format!("--frames-from {}: no usable checkpoint", dir.display())
            })?;
            let seed = loaded.variation_seed(None);
            by_experiment
                .entry(run.experiment.clone())
                .or_default()
                .push(Source { run, loaded, seed });
        }
        // The camera exists (every Meta-World scene has the same cameras) and GL works.
        if let Some(task) = by_experiment
            .values()
            .flatten()
            .flat_map(|s| &s.loaded.tasks)
            .next()
        {
            let env = Env::for_rendering(task.name)?;
            let renderer = Renderer::new(&env.scene().sim, 8, 8)?;
            anyhow::ensure!(
                renderer.cameras().iter().any(|c| c == camera),
                "--frames-camera {camera:?}: the scenes' cameras are {}",
                renderer.cameras().join(", ")
            );
        }
        Ok(Self {
            by_experiment,
            camera: camera.to_string(),
        })
    }
}

/// Renders the figure of `sources` into `out_dir/frames/` and returns the markdown section and
/// the files written.
pub(crate) fn section(sources: FrameSources, out_dir: &Path) -> Result<(String, Vec<PathBuf>)> {
    let FrameSources {
        by_experiment,
        camera,
    } = sources;
    let camera = camera.as_str();
    let frames_dir = out_dir.join("frames");
    std::fs::create_dir_all(&frames_dir)
        .with_context(|| format!("creating {}", frames_dir.display()))?;
    let mut md = String::new();
    let mut files = Vec::new();
    let _ = writeln!(
        md,
        "\n## What the final policies do (camera `{camera}`)\n\n\
         One deterministic episode per task and run (evaluation episode 0: goal variation 0 of \
         the run's variation seed), drawn by MuJoCo's renderer: after the reset, the first \
         success (else the frame nearest the goal, the highest reward among every {EVERY}th \
         step), and step 500. One row per run, from its checkpoint \
         (`terl report --frames-from`)."
    );
    for (exp, mut sources) in by_experiment {
        sources.sort_by(|a, b| {
            (a.run.algorithm.as_str(), a.run.seed).cmp(&(b.run.algorithm.as_str(), b.run.seed))
        });
        let _ = writeln!(md, "\n### {exp}\n");
        for s in &sources {
            let _ = writeln!(
                md,
                "- {} seed {}: `{}` (policy version {})",
                s.run.algorithm,
                s.run.seed,
                s.loaded.ckpt.path.display(),
                s.loaded.ckpt.policy.version
            );
        }
        // Every run's tasks, in the order they first appear.
        let mut task_names: Vec<&'static str> = Vec::new();
        for t in sources.iter().flat_map(|s| &s.loaded.tasks) {
            if !task_names.contains(&t.name) {
                task_names.push(t.name);
            }
        }
        for name in task_names {
            let mut env = Env::for_rendering(name)?;
            let mut renderer = Renderer::new(&env.scene().sim, SIDE, SIDE)?;
            let mut rows = Vec::new();
            let mut lines = Vec::new();
            for s in &sources {
                let Some(task) = s.loaded.tasks.iter().find(|t| t.name == name) else {
                    continue;
                };
                let variations = goal_variations(name, s.seed)?;
                let label = format!("{} s{}", s.run.algorithm, s.run.seed);
                let shot = Shot {
                    camera,
                    every: EVERY,
                    label: &label,
                };
                let got = record_episode(
                    &s.loaded.ckpt.policy,
                    task,
                    &mut env,
                    &mut renderer,
                    &variations,
                    0,
                    &shot,
                    None,
                    &|_| {},
                )
                .with_context(|| format!("rendering {name} for {label}"))?;
                let o = got.outcome;
                lines.push(format!(
                    "{label}: {}, return {:.1}",
                    o.first_success.map_or_else(
                        || "no success".to_string(),
                        |s| format!("success at step {s}")
                    ),
                    o.ret
                ));
                rows.push(got.tiles);
            }
            if rows.is_empty() {
                continue;
            }
            let file = format!("{}-{name}.png", file_stem(&exp));
            let path = frames_dir.join(&file);
            write_grid(&path, &rows)?;
            files.push(path);
            let _ = writeln!(
                md,
                "\n**{name}** — {}\n\n![{name}](frames/{file})",
                lines.join("; ")
            );
        }
    }
    Ok((md, files))
}
