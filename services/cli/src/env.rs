//! `terl env ...`: task listing and trace replay/comparison.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Subcommand;
use terl_sim::metaworld::{task_names, task_set, task_set_names};
use terl_sim::trace::{Comparison, Tolerance, Trace};

#[derive(Debug, Subcommand)]
pub enum EnvCommand {
    /// List the implemented tasks (Meta-World's 50, in its order) and the task sets.
    List {
        #[arg(long)]
        json: bool,
    },
    /// Replay a trace's actions through the Rust tasks and write the Rust trace.
    Replay {
        /// Input trace (.jsonl or .jsonl.gz).
        #[arg(long)]
        trace: PathBuf,
        /// Output trace (.jsonl; .gz compresses).
        #[arg(long)]
        out: PathBuf,
    },
    /// Compare two traces of the same episode: per-field max errors, non-zero exit over tolerance.
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Max absolute observation error.
        #[arg(long, value_parser = terl_runtime::flags::parse_scale, default_value_t = 1e-4)]
        obs_tol: f64,
        /// Max absolute reward error.
        #[arg(long, value_parser = terl_runtime::flags::parse_scale, default_value_t = 1e-3)]
        reward_tol: f64,
        #[arg(long)]
        json: bool,
    },
}

pub fn run(cmd: EnvCommand) -> Result<ExitCode> {
    match cmd {
        EnvCommand::List { json } => {
            let sets: Vec<(String, Vec<&str>)> = task_set_names()
                .iter()
                .map(|s| Ok((s.to_string(), task_set(s)?)))
                .collect::<Result<_>>()?;
            if json {
                let v = serde_json::json!({
                    "tasks": task_names(),
                    "task_sets": sets.iter().cloned().collect::<std::collections::BTreeMap<_, _>>(),
                });
                println!("{}", serde_json::to_string_pretty(&v)?);
            } else {
                println!("tasks ({}):", task_names().len());
                for t in task_names() {
                    println!("  {t}");
                }
                println!("task sets:");
                for (name, tasks) in sets {
                    println!("  {name:10} {:2} tasks: {}", tasks.len(), tasks.join(" "));
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        EnvCommand::Replay { trace, out } => {
            let input = Trace::read(&trace)?;
            let replayed = input
                .replay()
                .with_context(|| format!("replaying {}", trace.display()))?;
            replayed.write(&out)?;
            eprintln!(
                "replayed {} steps of {} into {}",
                replayed.steps.len() - 1,
                replayed.task,
                out.display()
            );
            Ok(ExitCode::SUCCESS)
        }
        EnvCommand::Compare {
            a,
            b,
            obs_tol,
            reward_tol,
            json,
        } => {
            let ta = Trace::read(&a)?;
            let tb = Trace::read(&b)?;
            if ta.task != tb.task {
                anyhow::bail!("traces are of different tasks: {} vs {}", ta.task, tb.task);
            }
            let c = Comparison::of(&ta, &tb);
            let tol = Tolerance {
                obs: obs_tol,
                reward: reward_tol,
            };
            let ok = c.within(tol);
            if json {
                let v = serde_json::json!({ "comparison": c, "tolerance": tol, "ok": ok });
                println!("{}", serde_json::to_string_pretty(&v)?);
            } else {
                println!("task              {}", c.task);
                println!("steps             {} vs {}", c.steps_a - 1, c.steps_b - 1);
                println!(
                    "obs max abs err   {:.3e} (step {}, index {}), tolerance {obs_tol:e}",
                    c.obs_max_abs, c.obs_worst.0, c.obs_worst.1
                );
                println!(
                    "reward max err    {:.3e} (step {}), tolerance {reward_tol:e}",
                    c.reward_max_abs, c.reward_worst_step
                );
                println!(
                    "success mismatch  {}{}",
                    c.success_mismatches,
                    c.first_success_mismatch
                        .map(|s| format!(" (first at step {s})"))
                        .unwrap_or_default()
                );
                println!("truncated mismatch {}", c.truncated_mismatches);
                println!("action mismatch   {}", c.action_mismatches);
                println!("{}", if ok { "OK" } else { "OVER TOLERANCE" });
            }
            Ok(if ok {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
    }
}
