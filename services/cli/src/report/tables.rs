//! What `terl report` writes across runs: `results.md` (the Table-I-style summary of
//! [`super::stats`]), `results.json`, and per experiment the evaluation success and return
//! curves (one line per algorithm, the IQM over seeds × tasks with its interval shaded), drawn
//! by [`super::charts`] as PNG (for documents) and SVG.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

use super::charts::{band, write_chart, Band, CurveMetric};
use super::runs::RunEval;
use super::stats::*;

fn steps_label(steps: (u64, u64)) -> String {
    let fmt = |s: u64| {
        if s >= 1_000_000 {
            format!("{:.2}M", s as f64 / 1e6)
        } else {
            format!("{:.0}k", s as f64 / 1e3)
        }
    };
    if steps.0 == steps.1 {
        fmt(steps.0)
    } else {
        format!("{}–{}", fmt(steps.0), fmt(steps.1))
    }
}

fn ci_cell(c: Option<&Ci>, digits: usize) -> String {
    c.map_or_else(|| "—".to_string(), |c| c.label(digits))
}

fn seeds_cell(stats: &FinalStats, g: &GroupSummary) -> String {
    if stats.seeds.len() == g.seeds.len() {
        stats.seeds.len().to_string()
    } else {
        format!("{} of {}", stats.seeds.len(), g.seeds.len())
    }
}

/// `results.md`: Table I with the field's statistics under both definitions of final success,
/// the probabilities of improvement, then a per-task breakdown per experiment.
#[allow(clippy::too_many_lines)] // one table after another, in reading order
pub fn markdown(summary: &Summary) -> String {
    let summaries = &summary.groups;
    let pct = 100.0 * summary.confidence;
    let mut s = String::new();
    let _ = writeln!(s, "# Evaluation results\n");
    let _ = writeln!(
        s,
        "Deterministic evaluations (mean action); success = success at any step of an episode. \
         The statistics follow Agarwal et al. 2021 (rliable): IQM = interquartile mean of the \
         seeds × tasks score matrix, mean = mean over tasks of the mean over seeds, each with a \
         {pct:.0} % stratified percentile-bootstrap interval (strata = tasks, seeds resampled \
         within each task; {} resamples, seed {:#x}); ± = sample std over seeds of each seed's \
         mean over tasks. The paper's Table I reports 5 seeds and 500 trials at its own budget; \
         Meta-World v3 tasks here use v2-style rewards.\n",
        summary.bootstrap_reps, summary.bootstrap_seed
    );
    let _ = writeln!(
        s,
        "## Final success: the final evaluation (`eval-final.json`, all goal variations)\n"
    );
    let _ = writeln!(
        s,
        "| experiment | algorithm | IQM % [{pct:.0} % CI] | mean % [{pct:.0} % CI] | mean ± std | paper % | seeds | eval episodes / task | env steps / run | networks |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    for g in summaries {
        let st = g.final_eval.as_ref();
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.1} ± {:.1} | {} | {} | {} | {} | {} |",
            g.experiment,
            g.algorithm,
            ci_cell(st.map(|f| &f.iqm), 1),
            ci_cell(st.map(|f| &f.mean), 1),
            g.success_mean,
            g.success_std,
            g.paper_success
                .map_or_else(|| "—".to_string(), |p| format!("{p:.1}")),
            st.map_or_else(|| g.seeds.len().to_string(), |f| seeds_cell(f, g)),
            g.episodes_per_task,
            steps_label(g.env_steps),
            g.networks
        );
    }
    for g in summaries
        .iter()
        .filter(|g| !g.without_final_eval.is_empty())
    {
        let _ = writeln!(
            s,
            "\n**Note:** {} / {}: {} run(s) without `eval-final.json`; their last in-run evaluation is their final one.",
            g.experiment,
            g.algorithm,
            g.without_final_eval.len()
        );
    }
    let last_k = summary.last_evals;
    let _ = writeln!(
        s,
        "\n## Final success: the mean of the last {last_k} in-run evaluations\n\n\
         Per run and task, the mean success of its last {last_k} in-run evaluations (`eval.mcap` or \
         `progress.jsonl`; fewer when the run has fewer), then the same statistics.\n"
    );
    let _ = writeln!(
        s,
        "| experiment | algorithm | IQM % [{pct:.0} % CI] | mean % [{pct:.0} % CI] | mean ± std | seeds | evaluations / run | eval episodes / task | at env steps |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    let mut none = Vec::new();
    for g in summaries {
        let Some(st) = &g.last_in_run else {
            none.push(format!("{} / {}", g.experiment, g.algorithm));
            continue;
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.1} ± {:.1} | {} | {} | {} | {} |",
            g.experiment,
            g.algorithm,
            st.iqm.label(1),
            st.mean.label(1),
            st.mean.point,
            st.std,
            seeds_cell(st, g),
            if st.evals_used.0 == st.evals_used.1 {
                st.evals_used.0.to_string()
            } else {
                format!("{}–{}", st.evals_used.0, st.evals_used.1)
            },
            st.episodes_per_task,
            steps_label(st.env_steps)
        );
    }
    if !none.is_empty() {
        let _ = writeln!(
            s,
            "\nNo in-run evaluations (evaluation-only folders): {}.",
            none.join(", ")
        );
    }
    if !summary.comparisons.is_empty() {
        let _ = writeln!(
            s,
            "\n## Probability of improvement\n\n\
             P(X > Y): the probability that a seed of X scores higher than a seed of Y on a task \
             (ties count ½), averaged over tasks (rliable `probability_of_improvement`), with its \
             {pct:.0} % stratified bootstrap interval (X and Y resampled independently). 0.5 is no \
             difference.\n"
        );
        let _ = writeln!(
            s,
            "| experiment | X | Y | P(X > Y), final evaluation | P(X > Y), last {last_k} in-run evaluations |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|");
        for c in &summary.comparisons {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                c.experiment,
                c.x,
                c.y,
                ci_cell(c.final_eval.as_ref(), 2),
                ci_cell(c.last_in_run.as_ref(), 2)
            );
        }
    }
    let mut experiments: Vec<&str> = summaries.iter().map(|g| g.experiment.as_str()).collect();
    experiments.dedup();
    for exp in experiments {
        let groups: Vec<&GroupSummary> = summaries.iter().filter(|g| g.experiment == exp).collect();
        let _ = writeln!(
            s,
            "\n## {exp}: per task (final evaluation success %, mean ± std over seeds)\n"
        );
        let header: Vec<String> = groups
            .iter()
            .map(|g| format!("{}, {}", g.algorithm, seeds_label(g.seeds.len())))
            .collect();
        let _ = writeln!(s, "| task | {} |", header.join(" | "));
        let _ = writeln!(s, "|---|{}", "---|".repeat(groups.len()));
        // Every task of any group, in the order the groups name them; a group's cell is found
        // by the task's name (groups of one experiment may cover different tasks).
        let mut tasks: Vec<&String> = Vec::new();
        for t in groups.iter().flat_map(|g| &g.tasks) {
            if !tasks.contains(&t) {
                tasks.push(t);
            }
        }
        for task in tasks {
            let cells: Vec<String> = groups
                .iter()
                .map(|g| {
                    g.per_task
                        .iter()
                        .find(|(t, _, _)| t == task)
                        .map_or("—".into(), |(_, m, sd)| format!("{m:.1} ± {sd:.1}"))
                })
                .collect();
            let _ = writeln!(s, "| {task} | {} |", cells.join(" | "));
        }
        for g in &groups {
            for (seed, task) in &g.missing {
                let _ = writeln!(
                    s,
                    "\n**Note:** {} seed {seed} has no evaluation of {task}; that seed's mean is over its other tasks, and the IQM and mean leave the seed out.",
                    g.algorithm
                );
            }
        }
        let _ = writeln!(
            s,
            "\nCurves (IQM with its {pct:.0} % stratified bootstrap interval shaded): `{0}-eval-success.png` / `.svg`, `{0}-eval-return.png` / `.svg`.",
            file_stem(exp)
        );
    }
    s
}

fn distinct_seeds(runs: &[&RunEval]) -> usize {
    let mut seeds: Vec<u64> = runs.iter().map(|r| r.seed).collect();
    seeds.sort_unstable();
    seeds.dedup();
    seeds.len()
}

fn seeds_label(n: usize) -> String {
    if n == 1 {
        "1 seed".into()
    } else {
        format!("{n} seeds")
    }
}

/// A file-name-safe form of an experiment name: ASCII letters, digits and `-` kept, anything
/// else `_`, at most 60 characters; when that changed the name (or it was empty), an FNV-1a
/// hash of the name is appended, so distinct names never share a chart file.
pub fn file_stem(experiment: &str) -> String {
    let safe: String = experiment
        .chars()
        .take(60)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if safe == experiment && !safe.is_empty() {
        return safe;
    }
    let hash = experiment.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{safe}-{:08x}", hash as u32)
}

/// Everything `terl report` writes for a set of runs: `results.md`, `results.json` and the
/// two charts per experiment. Returns the markdown and the files written.
pub fn write_results(
    runs: &[RunEval],
    out_dir: &Path,
    opts: &StatsOptions,
) -> Result<(String, Vec<PathBuf>)> {
    let summary = summary(runs, opts)?;
    let md = markdown(&summary);
    let mut files = Vec::new();
    let md_path = out_dir.join("results.md");
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    files.push(md_path);
    let json_path = out_dir.join("results.json");
    let json = serde_json::json!({
        "groups": summary.groups,
        "comparisons": summary.comparisons,
        "last_evals": summary.last_evals,
        "bootstrap_reps": summary.bootstrap_reps,
        "confidence": summary.confidence,
        "bootstrap_seed": summary.bootstrap_seed,
        "runs": runs,
    });
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("writing {}", json_path.display()))?;
    files.push(json_path);
    let groups = group_runs(runs);
    let mut experiments: Vec<&String> = groups.keys().map(|(e, _)| e).collect();
    experiments.dedup();
    for exp in experiments {
        for metric in [CurveMetric::Success, CurveMetric::Return] {
            let bands: Vec<Band> = groups
                .iter()
                .filter(|((e, _), _)| e == exp)
                .filter_map(|((_, alg), members)| {
                    band(
                        &format!("{alg}, {}", seeds_label(distinct_seeds(members))),
                        members,
                        metric,
                        &opts.bootstrap,
                    )
                    .transpose()
                })
                .collect::<Result<_>>()?;
            let (stem, what) = match metric {
                CurveMetric::Success => ("eval-success", "success"),
                CurveMetric::Return => ("eval-return", "return"),
            };
            files.extend(write_chart(
                out_dir,
                &format!("{}-{stem}", file_stem(exp)),
                &format!(
                    "{exp}: deterministic evaluation {what} (IQM, {:.0} % stratified bootstrap CI)",
                    100.0 * opts.bootstrap.confidence
                ),
                metric,
                &bands,
            )?);
        }
    }
    Ok((md, files))
}
