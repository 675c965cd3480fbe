//! `terl bench ...`: benchmarks that print one JSON object.

use std::process::ExitCode;

use anyhow::Result;
use clap::Subcommand;

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Env steps/s per task against the bare physics rate of the same model.
    Env {
        /// Task set or comma-separated task names.
        #[arg(long, default_value = "mt10")]
        tasks: String,
        /// Seconds per measurement.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
        /// Print JSON (the default output is JSON too; the flag is accepted for scripts).
        #[arg(long)]
        json: bool,
    },
    /// Transitions/s through iceoryx2 shared memory (1 and N publishers into one subscriber)
    /// and, in the same run, over a tonic stream on loopback.
    Transport {
        /// Publishers of the N-publisher measurement.
        #[arg(long, default_value_t = 3)]
        publishers: usize,
        /// Seconds per measurement.
        #[arg(long, default_value_t = 3.0)]
        seconds: f64,
        #[arg(long)]
        json: bool,
    },
    /// Latency from publishing a new 3×400 policy version to its receipt by every one of N
    /// subscribed gRPC clients (p50/p95/max).
    Broadcast {
        #[arg(long, default_value_t = 8)]
        subscribers: usize,
        /// Versions to publish.
        #[arg(long, default_value_t = 30)]
        versions: u64,
        #[arg(long)]
        json: bool,
    },
    /// Full SAC updates per second, achieved GFLOP/s against the same-run GEMM rate, and
    /// batch-8 policy inference latency.
    Sac {
        /// Policy input width: observation plus one-hot task id (39 + 10 for MT10).
        #[arg(long, default_value_t = 49)]
        obs_dim: usize,
        #[arg(long, default_value_t = 4)]
        act_dim: usize,
        /// Width of every hidden layer.
        #[arg(long, default_value_t = 400)]
        hidden: usize,
        /// Number of hidden layers.
        #[arg(long, default_value_t = 3)]
        layers: usize,
        #[arg(long, default_value_t = 1280)]
        batch: usize,
        #[arg(long, default_value_t = 2)]
        threads: usize,
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Tasks in the one-hot part of obs-dim.
        #[arg(long, default_value_t = 10)]
        num_tasks: usize,
        #[arg(long)]
        json: bool,
    },
}

pub fn run(cmd: BenchCommand) -> Result<ExitCode> {
    match cmd {
        BenchCommand::Env { tasks, seconds, .. } => {
            anyhow::ensure!(
                seconds > 0.0 && seconds.is_finite(),
                "--seconds must be positive"
            );
            let tasks = terl_runtime::resolve_tasks(&tasks)?;
            let report = terl_sim::bench::env_bench(&tasks, seconds)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Transport {
            publishers,
            seconds,
            ..
        } => {
            anyhow::ensure!(
                seconds > 0.0 && seconds.is_finite(),
                "--seconds must be positive"
            );
            anyhow::ensure!(publishers >= 1, "--publishers must be at least 1");
            let one = terl_transport::bench::shm_throughput(1, seconds)?;
            let many = terl_transport::bench::shm_throughput(publishers, seconds)?;
            let grpc = terl_wire::bench::grpc_transition_stream(seconds)?;
            let best_shm = one.transitions_per_sec.min(many.transitions_per_sec);
            let report = serde_json::json!({
                "shm_1_publisher": one,
                "shm_n_publishers": many,
                "grpc_stream": grpc,
                "shm_over_grpc": best_shm / grpc.transitions_per_second,
                "zero_loss": one.lost_batches == 0 && many.lost_batches == 0
                    && one.out_of_order == 0 && many.out_of_order == 0,
            });
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Broadcast {
            subscribers,
            versions,
            ..
        } => {
            anyhow::ensure!(subscribers >= 1, "--subscribers must be at least 1");
            anyhow::ensure!(versions >= 1, "--versions must be at least 1");
            let report = terl_wire::bench::broadcast_latency(subscribers, versions)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Sac {
            obs_dim,
            act_dim,
            hidden,
            layers,
            batch,
            threads,
            seconds,
            num_tasks,
            ..
        } => {
            anyhow::ensure!(
                seconds > 0.0 && seconds.is_finite(),
                "--seconds must be positive"
            );
            anyhow::ensure!(threads > 0, "--threads must be at least 1");
            anyhow::ensure!(
                num_tasks < obs_dim,
                "--num-tasks must be smaller than --obs-dim (it is part of it)"
            );
            let cfg = terl_rl::bench::SacBenchConfig {
                obs_dim,
                act_dim,
                hidden,
                layers,
                batch,
                threads,
                seconds,
                num_tasks,
            };
            let report = terl_rl::bench::sac_bench(&cfg)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
    }
}
