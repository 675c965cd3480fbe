//! Learning-curve charts of `terl report`: per experiment, one line per algorithm, the IQM
//! over seeds × tasks (Agarwal et al. 2021, rliable `aggregate_iqm`) with its stratified
//! bootstrap interval shaded, drawn by `plotters` as PNG (text rendered from DejaVu Sans) and
//! SVG.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use plotters::prelude::*;

use terl_stats::{Bootstrap, ScoreMatrix};

use super::runs::{EvalPoint, RunEval};

/// Which evaluation quantity a curve shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CurveMetric {
    /// Mean success over tasks, in %.
    Success,
    /// Mean episode return.
    Return,
}

impl CurveMetric {
    fn label(self) -> &'static str {
        match self {
            Self::Success => "evaluation success (%)",
            Self::Return => "evaluation episode return",
        }
    }
}

/// One curve of a chart: an algorithm's IQM with its stratified bootstrap interval, on a
/// common grid of env steps. Each (seed, task) curve is linearly interpolated onto the grid,
/// which runs from the first to the last env steps that every such curve evaluated.
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    pub label: String,
    /// `(env steps, IQM, interval lower, interval upper)`.
    pub points: Vec<(f64, f64, f64, f64)>,
}

fn interpolate(points: &[(f64, f64)], x: f64) -> f64 {
    match points.iter().position(|&(px, _)| px >= x) {
        Some(0) => points[0].1,
        Some(i) => {
            let ((x0, y0), (x1, y1)) = (points[i - 1], points[i]);
            if x1 == x0 {
                y1
            } else {
                y0 + (y1 - y0) * (x - x0) / (x1 - x0)
            }
        }
        None => points.last().map_or(f64::NAN, |p| p.1),
    }
}

/// The union of the curves' x values inside the range every curve covers: no invented
/// resolution. Curves must be non-empty and sorted by x.
fn common_grid<'a>(curves: impl Iterator<Item = &'a Vec<(f64, f64)>> + Clone) -> Vec<f64> {
    let lo = curves.clone().map(|c| c[0].0).fold(f64::MIN, f64::max);
    let hi = curves
        .clone()
        .map(|c| c[c.len() - 1].0)
        .fold(f64::MAX, f64::min);
    if hi <= lo {
        return vec![lo];
    }
    let mut xs: Vec<f64> = curves
        .flat_map(|c| c.iter().map(|p| p.0))
        .filter(|&x| x >= lo && x <= hi)
        .collect();
    xs.sort_by(f64::total_cmp);
    xs.dedup();
    xs
}

/// The band of one group of runs. Success: one curve per seed and task (a multi-task run gives
/// all its tasks, runs of tasks trained alone one each); return, which runs log only as a mean
/// over their tasks: one curve per seed and run. At each grid point the seeds × curves matrix
/// (seeds lacking a curve that another seed has are left out) gives the IQM and its stratified
/// bootstrap interval ([`terl_stats`], strata = tasks).
pub fn band(
    label: &str,
    runs: &[&RunEval],
    metric: CurveMetric,
    bootstrap: &Bootstrap,
) -> Result<Option<Band>> {
    // seed → column (task, or the run's task list) → curve.
    let mut by_seed: BTreeMap<u64, BTreeMap<String, Vec<(f64, f64)>>> = BTreeMap::new();
    for r in runs.iter().filter(|r| !r.points.is_empty()) {
        let seed = by_seed.entry(r.seed).or_default();
        let curve = |f: &dyn Fn(&EvalPoint) -> f64| -> Vec<(f64, f64)> {
            r.points
                .iter()
                .map(|p| (p.env_steps as f64, f(p)))
                .collect()
        };
        match metric {
            CurveMetric::Success => {
                for (k, t) in r.tasks.iter().enumerate() {
                    seed.insert(t.clone(), curve(&|p| 100.0 * p.per_task_success[k]));
                }
            }
            CurveMetric::Return => {
                seed.insert(r.tasks.join(","), curve(&|p| p.mean_return));
            }
        }
    }
    let mut columns: Vec<&String> = by_seed.values().flat_map(BTreeMap::keys).collect();
    columns.sort();
    columns.dedup();
    let complete: Vec<&BTreeMap<String, Vec<(f64, f64)>>> = by_seed
        .values()
        .filter(|c| columns.iter().all(|k| c.contains_key(*k)))
        .collect();
    if complete.is_empty() || columns.is_empty() {
        return Ok(None);
    }
    let curves = || complete.iter().flat_map(|c| c.values());
    let mut points = Vec::new();
    for x in common_grid(curves()) {
        let rows: Vec<Vec<f64>> = complete
            .iter()
            .map(|c| columns.iter().map(|k| interpolate(&c[*k], x)).collect())
            .collect();
        let i = bootstrap.iqm(&ScoreMatrix::from_rows(&rows)?)?;
        points.push((x, i.point, i.lower, i.upper));
    }
    Ok(Some(Band {
        label: label.to_string(),
        points,
    }))
}

const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    title: &str,
    metric: CurveMetric,
    bands: &[Band],
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow::anyhow!("{e}"))?;
    let x_max = bands
        .iter()
        .flat_map(|b| b.points.iter().map(|p| p.0))
        .fold(1.0f64, f64::max);
    let (y_min, y_max) = match metric {
        CurveMetric::Success => (0.0, 100.0),
        CurveMetric::Return => {
            let lo = bands
                .iter()
                .flat_map(|b| b.points.iter().map(|p| p.2))
                .fold(0.0f64, f64::min);
            let hi = bands
                .iter()
                .flat_map(|b| b.points.iter().map(|p| p.3))
                .fold(1.0f64, f64::max);
            (lo, hi * 1.05)
        }
    };
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(72)
        .build_cartesian_2d(0.0..x_max, y_min..y_max)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    chart
        .configure_mesh()
        .x_desc("environment steps")
        .y_desc(metric.label())
        .label_style(("sans-serif", 15))
        .x_label_formatter(&|x| {
            if x_max >= 1e6 {
                format!("{:.1}M", x / 1e6)
            } else if x_max >= 1e4 {
                format!("{:.0}k", x / 1e3)
            } else {
                format!("{x:.0}")
            }
        })
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    for (i, b) in bands.iter().enumerate() {
        let color = PALETTE[i % PALETTE.len()];
        let clamp = |v: f64| v.clamp(y_min, y_max);
        let mut outline: Vec<(f64, f64)> = b
            .points
            .iter()
            .map(|&(x, _, _, hi)| (x, clamp(hi)))
            .collect();
        outline.extend(b.points.iter().rev().map(|&(x, _, lo, _)| (x, clamp(lo))));
        chart
            .draw_series(std::iter::once(Polygon::new(
                outline,
                color.mix(0.18).filled(),
            )))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        chart
            .draw_series(LineSeries::new(
                b.points.iter().map(|&(x, m, _, _)| (x, m)),
                color.stroke_width(2),
            ))
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .label(b.label.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
            });
        // Markers at the evaluations, so a curve of one point (a run with only its final
        // evaluation) still shows.
        chart
            .draw_series(
                b.points
                    .iter()
                    .map(|&(x, m, _, _)| Circle::new((x, m), 3, color.filled())),
            )
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 16))
        .draw()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    root.present().map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok(())
}

/// Writes `<stem>.png` and `<stem>.svg` (1000 × 560) of one chart.
pub fn write_chart(
    out_dir: &Path,
    stem: &str,
    title: &str,
    metric: CurveMetric,
    bands: &[Band],
) -> Result<Vec<PathBuf>> {
    crate::font::register_font()?;
    let png = out_dir.join(format!("{stem}.png"));
    let svg = out_dir.join(format!("{stem}.svg"));
    draw(
        BitMapBackend::new(&png, (1000, 560)).into_drawing_area(),
        title,
        metric,
        bands,
    )
    .with_context(|| format!("drawing {}", png.display()))?;
    draw(
        SVGBackend::new(&svg, (1000, 560)).into_drawing_area(),
        title,
        metric,
        bands,
    )
    .with_context(|| format!("drawing {}", svg.display()))?;
    Ok(vec![png, svg])
}
