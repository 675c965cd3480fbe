//! `terl planner train --dataset D.mcap... --updates N [--config RUN.toml] [--set KEY=VALUE]...
//! --out P.safetensors`: F and AN trained offline ("training the planner separately", paper
//! Sec. V) with the learner's own parts: the datasets go into a [`TepBuffer`] one segment per
//! trajectory, minibatches are drawn with the config's hindsight sampling, and each step is
//! [`Tep::update`]. The planner file holds F, AN and their targets with the config in its
//! metadata (`terl.tep_config`), the format of a learner's `checkpoints/planner.safetensors`;
//! a JSON-lines log of the losses (and of ρ on `--eval-dataset`) goes to `P.train.jsonl`.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;
use terl_runtime::flags;

use anyhow::{Context, Result};
use clap::Args;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_nn::par_for_threads;
use terl_rl::planner_eval::{predict_gaps, score, PairSet};
use terl_rl::{Tep, TepBatch, TepBuffer, TepConfig};
use terl_wire::{ACTION_DIM, OBS_DIM};

use super::files::{check_output, partial_path, read_trajectories, split_held_out, Trajectory};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// TEP datasets to train on (repeatable).
    #[arg(long = "dataset", required = true)]
    pub datasets: Vec<PathBuf>,
    /// Planner updates.
    #[arg(long, value_parser = flags::count::<u64>(flags::MAX_STEPS), default_value_t = 5000)]
    pub updates: u64,
    /// A run file (its `[tep]` table) or a TOML file of planner settings.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// A planner setting over the config, TOML value syntax (`f_target="gap"`,
    /// `f_hidden=[256,256]`); repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Held-out datasets: Spearman ρ of F on them is logged every `--eval-every` updates.
    #[arg(long = "eval-dataset")]
    pub eval_datasets: Vec<PathBuf>,
    /// Leave out the first K trajectories of each task of `--dataset` (the ones `terl planner
    /// eval --hold-out-trajectories K` scores), so one dataset of a run serves training and
    /// evaluation; they are used as the held-out check of the log lines when no
    /// `--eval-dataset` is given.
    #[arg(long, value_parser = flags::count_or_zero::<usize>(flags::MAX_HOLD_OUT), default_value_t = 0, value_name = "K")]
    pub hold_out_trajectories: usize,
    /// Updates between log lines (and held-out checks).
    #[arg(long, value_parser = flags::count::<u64>(flags::MAX_STEPS), default_value_t = 500)]
    pub eval_every: u64,
    /// Seed of initialisation and sampling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Threads of the update (default: the config's `threads`).
    #[arg(long, value_parser = flags::count::<usize>(flags::MAX_THREADS))]
    pub threads: Option<usize>,
    /// Use a damaged or incomplete dataset up to its damage (default: refuse it).
    #[arg(long)]
    pub accept_partial: bool,
    /// The planner file to write (replaced if it exists; written to a temporary file and renamed,
    /// so a killed run leaves the old one). The log goes beside it: `P.train.jsonl`.
    #[arg(long)]
    pub out: PathBuf,
}

/// The planner settings: `[tep]` of a run file (or the whole file), then `--set` overrides.
pub fn planner_config(path: Option<&Path>, set: &[String]) -> Result<TepConfig> {
    let mut table = match path {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read {}", p.display()))?;
            let mut t: toml::Table =
                toml::from_str(&text).with_context(|| format!("{} is not TOML", p.display()))?;
            match t.remove("tep") {
                Some(toml::Value::Table(tep)) => tep,
                Some(_) => anyhow::bail!("{}: [tep] is not a table", p.display()),
                None if t.contains_key("cluster") || t.contains_key("sac") => toml::Table::new(),
                None => t,
            }
        }
        None => toml::Table::new(),
    };
    for kv in set {
        let (k, v) = kv
            .split_once('=')
            .with_context(|| format!("--set {kv:?}: expected KEY=VALUE"))?;
        anyhow::ensure!(
            !["obs_dim", "act_dim", "seed", "threads"].contains(&k.trim()),
            "--set {kv:?}: {} comes from the datasets or the command line (--seed, --threads), \
             not from --set",
            k.trim()
        );
        let parsed: toml::Table = toml::from_str(&format!("v = {}", v.trim()))
            .with_context(|| format!("--set {kv:?}: the value is not TOML"))?;
        table.insert(k.trim().to_string(), parsed["v"].clone());
    }
    let text = toml::to_string(&table)?;
    let mut cfg = TepConfig::from_toml(&text).context("planner settings")?;
    cfg.obs_dim = OBS_DIM;
    cfg.act_dim = ACTION_DIM;
    cfg.validate()?;
    Ok(cfg)
}

/// Evaluation pairs of the held-out trajectories (up to each first success, at most
/// `max_pairs` per trajectory), with task indices into `tasks`.
pub fn held_out_pairs(
    trajectories: &[Trajectory],
    tasks: &mut Vec<String>,
    max_pairs: usize,
    seed: u64,
) -> PairSet {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut pairs = PairSet::new(OBS_DIM, ACTION_DIM);
    for t in trajectories {
        let k = match tasks.iter().position(|x| *x == t.task) {
            Some(k) => k,
            None => {
                tasks.push(t.task.clone());
                tasks.len() - 1
            }
        };
        let n = t.until_success();
        if n == 0 {
            continue;
        }
        // The true step gap comes from the recorded step numbers, so selected data (which may
        // skip steps) gives pairs as scripted data does.
        pairs.add_segment(
            k,
            &t.steps[..n],
            &t.obs[..n * OBS_DIM],
            &t.actions[..n * ACTION_DIM],
            &t.next_obs[..n * OBS_DIM],
            max_pairs,
            &mut rng,
        );
    }
    pairs
}

/// Fills a TEP buffer with the trajectories (one segment each), each up to and including its
/// first success ([`Trajectory::until_success`]): after it a Meta-World episode hovers at the
/// goal, states whose step gaps F cannot tell apart (the learner leaves them out too).
pub fn fill_buffer(trajectories: &[Trajectory], tasks: &[String]) -> Result<TepBuffer> {
    let total: usize = trajectories.iter().map(Trajectory::until_success).sum();
    let mut buffer = TepBuffer::new(total.max(1), OBS_DIM, ACTION_DIM);
    for t in trajectories {
        let n = t.until_success();
        if n == 0 {
            continue;
        }
        let task = tasks.iter().position(|x| *x == t.task).unwrap_or(0) as u32;
        buffer.push_segment(
            task,
            t.id,
            &t.steps[..n],
            &t.obs[..n * OBS_DIM],
            &t.actions[..n * ACTION_DIM],
            &t.next_obs[..n * OBS_DIM],
        )?;
    }
    Ok(buffer)
}

#[allow(clippy::too_many_lines)] // the offline planner training steps in order (load, split, train, evaluate, write)
pub fn run(args: TrainArgs) -> Result<ExitCode> {
    let mut cfg = planner_config(args.config.as_deref(), &args.set)?;
    cfg.seed = args.seed;
    if let Some(t) = args.threads {
        anyhow::ensure!((1..=256).contains(&t), "--threads must be in 1..=256");
        cfg.threads = t;
    }
    anyhow::ensure!(args.updates > 0, "--updates must be ≥ 1");
    anyhow::ensure!(args.eval_every > 0, "--eval-every must be ≥ 1");
    let log_path = log_path(&args.out);
    let mut inputs: Vec<&Path> = args
        .datasets
        .iter()
        .chain(&args.eval_datasets)
        .map(PathBuf::as_path)
        .collect();
    inputs.extend(args.config.as_deref());
    if let Some(init) = &cfg.init_planner {
        inputs.push(Path::new(init));
    }
    check_output(&args.out, "--out", &inputs)?;
    check_output(&log_path, "the training log", &inputs)?;
    for e in &args.eval_datasets {
        let canonical = std::fs::canonicalize(e).ok();
        anyhow::ensure!(
            !args
                .datasets
                .iter()
                .any(|d| canonical.is_some() && std::fs::canonicalize(d).ok() == canonical),
            "--eval-dataset {} is also a --dataset: held-out ρ would be measured on training \
             data (--hold-out-trajectories K holds out part of one dataset)",
            e.display()
        );
    }
    let (trajectories, split_off) = split_held_out(
        read_trajectories(&args.datasets, args.accept_partial)?,
        args.hold_out_trajectories,
    );
    anyhow::ensure!(
        !trajectories.is_empty(),
        "no trajectory left to train on after holding out the first {} of each task",
        args.hold_out_trajectories
    );
    for t in &split_off {
        if !trajectories.iter().any(|x| x.task == t.task) {
            eprintln!(
                "[planner train] {}: every trajectory is held out; the planner gets no training \
                 data of this task",
                t.task
            );
        }
    }
    let mut tasks: Vec<String> = Vec::new();
    for t in &trajectories {
        if !tasks.contains(&t.task) {
            tasks.push(t.task.clone());
        }
    }
    let buffer = fill_buffer(&trajectories, &tasks)?;
    let held_out = if !args.eval_datasets.is_empty() {
        let mut eval_tasks = tasks.clone();
        let t = read_trajectories(&args.eval_datasets, args.accept_partial)?;
        Some(held_out_pairs(&t, &mut eval_tasks, 64, 1))
    } else if !split_off.is_empty() {
        let mut eval_tasks = tasks.clone();
        Some(held_out_pairs(&split_off, &mut eval_tasks, 64, 1))
    } else {
        None
    };
    tracing::info!(
        transitions = buffer.len(),
        trajectories = trajectories.len(),
        tasks = tasks.len(),
        "planner training data"
    );
    let mut tep: Tep<f32> = Tep::new(cfg.clone())?;
    if let Some(init) = &cfg.init_planner {
        // Continue from a planner file of the same networks (fine-tuning, more updates).
        let start = super::files::load_planner(std::path::Path::new(init))?;
        anyhow::ensure!(
            start.config().f_output_scale == cfg.f_output_scale,
            "init_planner {init} has f_output_scale {}, these settings {}",
            start.config().f_output_scale,
            cfg.f_output_scale
        );
        let file = terl_nn::tensors::TensorFile::from_tensors(start.planner_file_tensors());
        tep.import_planner(&file)
            .with_context(|| format!("init_planner {init} does not fit these networks"))?;
        eprintln!("[planner train] starting from {init}");
    }
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed ^ 0x7e9_5a3d);
    let mut batch = TepBatch::with_capacity(cfg.batch_size, OBS_DIM, ACTION_DIM);
    // The log is written beside its final name and renamed with the planner, so a killed run
    // leaves the previous planner and log together.
    let log_partial = partial_path(&log_path);
    let mut log = std::io::BufWriter::new(
        std::fs::File::create(&log_partial)
            .with_context(|| format!("cannot create {}", log_partial.display()))?,
    );
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = indicatif::ProgressBar::new(args.updates);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} updates  {elapsed_precise} (eta {eta})  {msg}",
        ) {
            b.set_style(style);
        }
        b
    });
    let started = Instant::now();
    let mut window = Window::default();
    let sampling = cfg.goal_sampling();
    for u in 1..=args.updates {
        buffer.sample_into_with(cfg.batch_size, &mut rng, &mut batch, sampling)?;
        let st = tep.update(&batch)?;
        window.add(&st);
        if u % args.eval_every == 0 || u == args.updates {
            let mut line = window.take(u, started.elapsed().as_secs_f64());
            if let Some(pairs) = &held_out {
                let pred = predict_gaps(&tep, pairs, par_for_threads(cfg.threads));
                let s = score(&pred, &pairs.gaps);
                line.insert("held_out_spearman".into(), s.spearman.into());
                for b in &s.bins {
                    line.insert(
                        format!("held_out_rel_err_{}_{}", b.lo, b.hi.min(9999)),
                        b.median_relative_error.into(),
                    );
                }
            }
            writeln!(log, "{}", serde_json::Value::Object(line.clone()))
                .and_then(|()| log.flush())
                .with_context(|| format!("cannot write {}", log_partial.display()))?;
            let msg = format!(
                "F loss {:.3}  goal distance {:.1} (gap {:.1})  AN bc {:.3}{}",
                line["f_loss"].as_f64().unwrap_or(f64::NAN),
                line["goal_distance_mean"].as_f64().unwrap_or(f64::NAN),
                line["gap_mean"].as_f64().unwrap_or(f64::NAN),
                line["an_bc_loss"].as_f64().unwrap_or(f64::NAN),
                line.get("held_out_spearman")
                    .and_then(|v| v.as_f64())
                    .map(|r| format!("  held-out ρ {r:.3}"))
                    .unwrap_or_default()
            );
            match &bar {
                Some(b) => b.set_message(msg),
                None => eprintln!("[planner train] update {u}: {msg}"),
            }
        }
        if let Some(b) = &bar {
            b.inc(1);
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let mut meta = BTreeMap::new();
    meta.insert("format".to_string(), "pt".to_string());
    meta.insert(
        "terl.tep_config".to_string(),
        toml::to_string(tep.config())?,
    );
    meta.insert("terl.tep_updates".to_string(), tep.updates().to_string());
    meta.insert("terl.tep_tasks".to_string(), tasks.join(","));
    log.into_inner()
        .map_err(|e| e.into_error())
        .and_then(|f| f.sync_all())
        .with_context(|| format!("cannot write {}", log_partial.display()))?;
    terl_nn::tensors::save_file(&args.out, &tep.planner_file_tensors(), &meta)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    std::fs::rename(&log_partial, &log_path).with_context(|| {
        format!(
            "cannot rename {} to {}",
            log_partial.display(),
            log_path.display()
        )
    })?;
    eprintln!(
        "[planner train] {} updates in {:.0} s on {} transitions of {} tasks → {} (log {})",
        tep.updates(),
        started.elapsed().as_secs_f64(),
        buffer.len(),
        tasks.len(),
        args.out.display(),
        log_path.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// `P.safetensors` → `P.train.jsonl`; any other name gets `.train.jsonl` appended
/// (`p-lr0.001` → `p-lr0.001.train.jsonl`, so two such names never share a log).
fn log_path(out: &Path) -> PathBuf {
    if out.extension().is_some_and(|e| e == "safetensors") {
        out.with_extension("train.jsonl")
    } else {
        let mut name = out.as_os_str().to_owned();
        name.push(".train.jsonl");
        PathBuf::from(name)
    }
}

/// Mean losses over the updates since the last log line.
#[derive(Default)]
struct Window {
    sums: BTreeMap<&'static str, f64>,
    n: u64,
}

impl Window {
    fn add(&mut self, st: &terl_rl::TepStats) {
        for (k, v) in [
            ("f_loss", st.f_loss),
            ("step_loss", st.step_loss),
            ("goal_loss", st.goal_loss),
            ("symmetry_loss", st.symmetry_loss),
            ("an_loss", st.an_loss),
            ("an_bc_loss", st.an_bc_loss),
            ("goal_distance_mean", st.goal_distance_mean),
            ("target_mean", st.target_mean),
            ("gap_mean", st.gap_mean),
        ] {
            *self.sums.entry(k).or_default() += v;
        }
        self.n += 1;
    }

    fn take(&mut self, update: u64, secs: f64) -> serde_json::Map<String, serde_json::Value> {
        let mut m = serde_json::Map::new();
        m.insert("update".into(), update.into());
        m.insert("seconds".into(), secs.into());
        for (k, v) in std::mem::take(&mut self.sums) {
            m.insert(k.into(), (v / self.n.max(1) as f64).into());
        }
        self.n = 0;
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trajectory(id: u64, len: u32, first_success: Option<u32>) -> Trajectory {
        let n = len as usize;
        Trajectory {
            task: "reach-v3".into(),
            id,
            variation: Some(0),
            steps: (0..len).collect(),
            obs: vec![0.0; n * OBS_DIM],
            actions: vec![0.0; n * ACTION_DIM],
            next_obs: vec![0.0; n * OBS_DIM],
            success: (0..len)
                .map(|k| first_success.is_some_and(|f| k >= f))
                .collect(),
        }
    }

    /// The offline buffer holds each trajectory up to and including its first success, and a
    /// trajectory that never succeeds whole (as the learner's buffer).
    #[test]
    fn the_buffer_ends_each_trajectory_at_its_first_success() {
        let tasks = vec!["reach-v3".to_string()];
        let b = fill_buffer(
            &[trajectory(1, 500, Some(60)), trajectory(2, 500, None)],
            &tasks,
        )
        .unwrap();
        assert_eq!(b.len(), 61 + 500);
        let last_of_first = (0..b.len())
            .map(|i| b.meta(i))
            .filter(|m| m.1 == 1)
            .map(|m| m.2)
            .max();
        assert_eq!(last_of_first, Some(60));
    }
}
