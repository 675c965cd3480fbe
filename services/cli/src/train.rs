//! `terl train --config FILE`: the single-process trainer (Meta-World envs + MTSAC in one
//! process). Used for debugging, tests and small runs; the distributed system runs the same
//! learner in its own process.

use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use clap::Args;
use terl_rl::train::{train, TrainProgress};
use terl_rl::Sac;
pub use terl_runtime::{MetaWorldVec, RunConfig};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Run configuration (TOML), e.g. deploy/configs/reach.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// Run folder (default: runs/<config name>-<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override the total number of environment steps.
    #[arg(long, value_parser = terl_runtime::flags::count::<u64>(terl_runtime::flags::MAX_STEPS))]
    pub steps: Option<u64>,
    /// Override the seed.
    #[arg(long)]
    pub seed: Option<u64>,
}

fn progress_line(tasks: &[&str], p: &TrainProgress) -> String {
    let train_sr = p.train_success.iter().sum::<f64>() / p.train_success.len().max(1) as f64;
    let mut s = format!(
        "env_steps {:>9}  updates {:>8}  episodes {:>6}  wall {:>7.1}s  train_success {:>5.1}%",
        p.env_steps,
        p.updates,
        p.episodes,
        p.wall_s,
        100.0 * train_sr
    );
    if let Some(e) = &p.eval {
        s.push_str(&format!("  eval_success {:>5.1}%", 100.0 * e.success_rate));
        if tasks.len() > 1 {
            let per: Vec<String> = tasks
                .iter()
                .zip(&e.per_task_success)
                .map(|(t, r)| format!("{}={:.0}%", t.trim_end_matches("-v3"), 100.0 * r))
                .collect();
            s.push_str(&format!("  [{}]", per.join(" ")));
        }
    }
    if let Some(u) = &p.last_update {
        s.push_str(&format!(
            "  qf1_loss {:.3}  actor_loss {:.3}",
            u.qf1_loss, u.actor_loss
        ));
    }
    s
}

/// Saves `sac` with its task list in order (metadata `terl.tasks`, a JSON array), so that a
/// copy of the checkpoint outside its run folder is still evaluated with the right one-hot
/// slots ([`terl_runtime::eval::load_policy_checkpoint`]).
fn save_checkpoint(sac: &Sac<f32>, tasks: &[String], path: &std::path::Path) -> Result<()> {
    let (tensors, mut meta) = sac.checkpoint_tensors();
    meta.insert(
        terl_runtime::eval::TASKS_KEY.to_string(),
        serde_json::to_string(tasks)?,
    );
    terl_nn::tensors::save_file(path, &tensors, &meta)
        .with_context(|| format!("cannot write the checkpoint {}", path.display()))
}

pub fn run(args: TrainArgs) -> Result<std::process::ExitCode> {
    let mut cfg = RunConfig::load(&args.config)?;
    if let Some(s) = args.steps {
        cfg.train.total_env_steps = s;
    }
    if let Some(s) = args.seed {
        cfg.train.seed = s;
        cfg.sac.seed = s;
    }
    let tasks = terl_runtime::resolve_tasks(&cfg.tasks)?;
    anyhow::ensure!(
        cfg.algorithm != terl_runtime::Algorithm::Terl,
        "{}: algorithm = \"terl\" runs in a cluster only (its selector, planner and guided \
         actors are processes): ./deploy/local-cluster.sh --config {}; terl train trains \
         \"mtsac\" and \"care\"",
        args.config.display(),
        args.config.display()
    );
    // The trainer gives environment k the task k mod tasks: fewer environments than tasks
    // would leave the last tasks untrained (the cluster's actors round up instead).
    anyhow::ensure!(
        cfg.num_envs >= tasks.len(),
        "{}: num_envs = {} is fewer than the run's {} tasks, so some tasks would never be \
         trained; set num_envs to at least {}",
        args.config.display(),
        cfg.num_envs,
        tasks.len(),
        tasks.len()
    );
    cfg.sac = cfg.sac_config(tasks.len());
    cfg.sac.validate()?;

    let stem = args
        .config
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "run".into());
    let out = args.out.unwrap_or_else(|| {
        let t = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        PathBuf::from("runs").join(format!("{stem}-{t}"))
    });
    // Another run's folder is never written into: its checkpoints and config would be
    // replaced and its logs mixed with this run's.
    anyhow::ensure!(
        !crate::cluster::launcher::holds_files(&out),
        "--out {} already exists and is not an empty folder: choose a new folder",
        out.display()
    );
    std::fs::create_dir_all(out.join("checkpoints"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(out.join("config.toml"), toml::to_string_pretty(&cfg)?)?;

    let mut env = MetaWorldVec::new(&tasks, cfg.num_envs, cfg.variation_seed)?;
    let mut eval_env = MetaWorldVec::new(
        &tasks,
        tasks.len() * cfg.eval_envs_per_task,
        cfg.variation_seed,
    )?;
    let task_names: Vec<String> = tasks.iter().map(|t| t.to_string()).collect();
    let mut sac = Sac::for_tasks(cfg.sac.clone(), &task_names)?;
    eprintln!(
        "training {} task(s) [{}] with {} envs, {} env steps; run folder {}",
        tasks.len(),
        tasks.join(", "),
        cfg.num_envs,
        cfg.train.total_env_steps,
        out.display()
    );
    let progress_path = out.join("progress.jsonl");
    let mut progress_file = std::fs::File::create(&progress_path)?;
    let mut io_error: Option<std::io::Error> = None;
    let report = train(&mut sac, &mut env, &mut eval_env, &cfg.train, |p, sac| {
        use std::io::Write;
        eprintln!("{}", progress_line(&tasks, p));
        let line = serde_json::to_string(p).expect("progress serialises");
        if let Err(e) = writeln!(progress_file, "{line}") {
            io_error.get_or_insert(e);
        }
        if p.eval.is_some() {
            if let Err(e) = save_checkpoint(
                sac,
                &task_names,
                &out.join("checkpoints/latest.safetensors"),
            ) {
                tracing::warn!("checkpoint failed: {e}");
            }
        }
    })?;
    if let Some(e) = io_error {
        return Err(e).context("writing progress.jsonl");
    }
    save_checkpoint(
        &sac,
        &task_names,
        &out.join("checkpoints/final.safetensors"),
    )?;
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    let target = match (
        report.reached_target_at_env_steps,
        report.reached_target_at_wall_s,
    ) {
        (Some(steps), Some(s)) => format!("target reached at {steps} env steps, {s:.0} s"),
        (Some(steps), None) => format!("target reached at {steps} env steps"),
        _ if cfg.train.stop_at_eval_success.is_some() => "target not reached".to_string(),
        _ => "no target set".to_string(),
    };
    eprintln!(
        "done: best eval success {:.1}% ({target}); report in {}",
        100.0 * report.best_eval_success,
        out.join("report.json").display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}
