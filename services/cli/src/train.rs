//! `terl train --config FILE`: the single-process trainer (Meta-World envs + MTSAC in one
//! process). Used for debugging, tests and small runs; the distributed system runs the same
//! learner in its own process.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result};
use clap::Args;
use serde::{Deserialize, Serialize};
use terl_rl::env::{StepBuffers, VecEnvironment};
use terl_rl::train::{train, TrainConfig, TrainProgress};
use terl_rl::{Sac, SacConfig};
use terl_sim::{VecEnv, ACT_DIM, OBS_DIM};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Run configuration (TOML), e.g. deploy/configs/reach.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// Run folder (default: runs/<config name>-<unix time>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override the total number of environment steps.
    #[arg(long)]
    pub steps: Option<u64>,
    /// Override the seed.
    #[arg(long)]
    pub seed: Option<u64>,
}

/// The run file: which tasks, how many environments, and the trainer and SAC settings.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// A task set (`mt10`, `mt1-ind`, ...) or comma-separated task names.
    pub tasks: String,
    /// Training environments (spread round-robin over the tasks).
    pub num_envs: usize,
    /// Evaluation environments per task.
    #[serde(default = "one")]
    pub eval_envs_per_task: usize,
    /// Seed of the goal variations (50 per task).
    #[serde(default)]
    pub variation_seed: u64,
    #[serde(default)]
    pub train: TrainConfig,
    #[serde(default)]
    pub sac: SacConfig,
}

fn one() -> usize {
    1
}

impl RunConfig {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        let cfg: Self =
            toml::from_str(&text).with_context(|| format!("invalid config {}", path.display()))?;
        anyhow::ensure!(cfg.num_envs > 0, "num_envs must be at least 1");
        anyhow::ensure!(
            cfg.eval_envs_per_task > 0,
            "eval_envs_per_task must be at least 1"
        );
        Ok(cfg)
    }
}

/// Meta-World [`VecEnv`] behind the trainer's environment seam.
pub struct MetaWorldVec {
    inner: VecEnv,
    num_tasks: usize,
    task_ids: Vec<usize>,
}

impl std::fmt::Debug for MetaWorldVec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MetaWorldVec")
            .field("num_envs", &self.inner.num_envs())
            .finish()
    }
}

impl MetaWorldVec {
    /// `num_envs` environments over `tasks`; task ids are positions in `tasks`.
    pub fn new(tasks: &[&str], num_envs: usize, seed: u64) -> Result<Self> {
        let inner = VecEnv::round_robin(tasks, num_envs, seed)?;
        let task_ids = inner
            .env_tasks()
            .iter()
            .map(|&k| {
                let name = inner.tasks()[k];
                tasks
                    .iter()
                    .position(|t| terl_sim::metaworld::task_set(t).is_ok_and(|s| s == [name]))
                    .expect("task of the list")
            })
            .collect();
        Ok(Self {
            inner,
            num_tasks: tasks.len(),
            task_ids,
        })
    }
}

impl VecEnvironment for MetaWorldVec {
    type Error = terl_sim::SimError;

    fn num_envs(&self) -> usize {
        self.inner.num_envs()
    }
    fn obs_dim(&self) -> usize {
        OBS_DIM
    }
    fn act_dim(&self) -> usize {
        ACT_DIM
    }
    fn num_tasks(&self) -> usize {
        self.num_tasks
    }
    fn task_ids(&self) -> &[usize] {
        &self.task_ids
    }
    fn reset_all(&mut self, seed: u64, obs: &mut [f32]) -> Result<(), Self::Error> {
        self.inner.reset_all_seeded(seed)?;
        obs.copy_from_slice(self.inner.obs());
        Ok(())
    }
    fn step(&mut self, actions: &[f32], out: &mut StepBuffers) -> Result<(), Self::Error> {
        self.inner.step(actions)?;
        let v = &self.inner;
        out.obs.copy_from_slice(v.obs());
        for i in 0..v.num_envs() {
            let row = i * OBS_DIM..(i + 1) * OBS_DIM;
            if v.truncated()[i] {
                out.final_obs[row.clone()].copy_from_slice(&v.final_obs()[row]);
            } else {
                out.final_obs[row.clone()].copy_from_slice(&v.obs()[row]);
            }
        }
        out.reward.copy_from_slice(v.rewards());
        out.truncated.copy_from_slice(v.truncated());
        out.terminated.fill(false);
        out.success.copy_from_slice(v.success());
        Ok(())
    }
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

pub fn run(args: TrainArgs) -> Result<std::process::ExitCode> {
    let mut cfg = RunConfig::load(&args.config)?;
    if let Some(s) = args.steps {
        cfg.train.total_env_steps = s;
    }
    if let Some(s) = args.seed {
        cfg.train.seed = s;
        cfg.sac.seed = s;
    }
    let tasks = crate::bench::resolve_tasks(&cfg.tasks)?;
    cfg.sac.obs_dim = OBS_DIM;
    cfg.sac.act_dim = ACT_DIM;
    cfg.sac.num_tasks = tasks.len();
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
    std::fs::create_dir_all(out.join("checkpoints"))
        .with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(out.join("config.toml"), toml::to_string_pretty(&cfg)?)?;

    let mut env = MetaWorldVec::new(&tasks, cfg.num_envs, cfg.variation_seed)?;
    let mut eval_env = MetaWorldVec::new(
        &tasks,
        tasks.len() * cfg.eval_envs_per_task,
        cfg.variation_seed,
    )?;
    let mut sac = Sac::new(cfg.sac.clone())?;
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
            if let Err(e) = sac.save_checkpoint(&out.join("checkpoints/latest.safetensors")) {
                tracing::warn!("checkpoint failed: {e}");
            }
        }
    })?;
    if let Some(e) = io_error {
        return Err(e).context("writing progress.jsonl");
    }
    sac.save_checkpoint(&out.join("checkpoints/final.safetensors"))?;
    std::fs::write(
        out.join("report.json"),
        serde_json::to_string_pretty(&report)?,
    )?;
    eprintln!(
        "done: best eval success {:.1}% (target reached at {:?} env steps / {:?} s); report in {}",
        100.0 * report.best_eval_success,
        report.reached_target_at_env_steps,
        report.reached_target_at_wall_s.map(|s| s.round()),
        out.join("report.json").display()
    );
    Ok(std::process::ExitCode::SUCCESS)
}
