//! `terl bench ...`: benchmarks that print one JSON object. The measurements are crate
//! `terl-bench`'s; this module parses the flags and prints the reports.

pub mod netns;
pub mod tep;

use std::process::ExitCode;

use anyhow::Result;
use clap::Subcommand;
use terl_bench::args::{SacArgs, TepUpdateArgs};
use terl_runtime::flags;

/// Most environments per task the memory measurement (`bench env --memory`) builds.
const MAX_MEMORY_ENVS: u64 = 256;

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Env steps/s per task against the bare physics rate of the same model; with `--memory`,
    /// RSS per environment instead (1 vs N environments of each task, each task in a fresh
    /// process, and an MT10 actor's 10-environment set) and the peak `mjData` arena use.
    Env {
        /// Task set or comma-separated task names.
        #[arg(long, default_value = "mt10")]
        tasks: String,
        /// Seconds per measurement.
        #[arg(long, value_parser = terl_runtime::parse_seconds, default_value_t = 2.0)]
        seconds: f64,
        /// Measure memory (RSS from /proc) instead of speed.
        #[arg(long)]
        memory: bool,
        /// With `--memory`: environments of each task in the N measurement (2 to 256).
        #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(2..=MAX_MEMORY_ENVS), default_value_t = 8)]
        envs: usize,
        /// With `--memory`: full episodes per task (random and scripted, alternating) over
        /// which the peak arena use is taken.
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_EPISODES), default_value_t = 20)]
        episodes: usize,
        /// Print JSON (the default output is JSON too; the flag is accepted for scripts).
        #[arg(long)]
        json: bool,
    },
    /// One memory probe in this fresh process (started by `env --memory`); prints JSON.
    #[command(hide = true)]
    EnvMemoryProbe {
        #[arg(long)]
        tasks: String,
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_ENVS))]
        envs: usize,
        /// 0: only the environments' memory, no episodes.
        #[arg(long, value_parser = flags::count_or_zero::<usize>(flags::MAX_EPISODES))]
        episodes: usize,
    },
    /// Transitions/s through iceoryx2 shared memory (1 and N publishers into one subscriber)
    /// and, in the same run, over a tonic stream on loopback.
    Transport {
        /// Publishers of the N-publisher measurement.
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_BENCH_PEERS), default_value_t = 3)]
        publishers: usize,
        /// Seconds per measurement.
        #[arg(long, value_parser = terl_runtime::parse_seconds, default_value_t = 3.0)]
        seconds: f64,
        /// Also measure this transport beside shared memory: `zenoh` (loopback TCP).
        #[arg(long, value_enum)]
        transport: Option<BenchTransport>,
        /// With `--transport zenoh`: also measure between two network namespaces (a veth
        /// pair, as between two hosts): the transition stream and the weight broadcast's
        /// latency. Needs root; everything it creates is removed at the end.
        #[arg(long, requires = "transport")]
        netns: bool,
        /// Weight versions published in the `--netns` broadcast measurement.
        #[arg(long, value_parser = flags::count::<u64>(flags::MAX_VERSIONS), default_value_t = 30)]
        versions: u64,
        /// gRPC subscribers of the `--netns` broadcast measurement.
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_BENCH_PEERS), default_value_t = 8)]
        subscribers: usize,
        #[arg(long)]
        json: bool,
    },
    /// The actors' half of `transport --netns` (run inside the namespace by it).
    #[command(hide = true)]
    TransportPublish {
        #[arg(long)]
        connect: String,
        /// The CA of the receiver's certificate (PEM).
        #[arg(long)]
        tls_ca: std::path::PathBuf,
        #[arg(long)]
        run_id: String,
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_BENCH_PEERS))]
        publishers: usize,
        #[arg(long, value_parser = terl_runtime::parse_seconds)]
        seconds: f64,
    },
    /// The subscribers' half of `transport --netns` (run inside the namespace by it).
    #[command(hide = true)]
    BroadcastSubscribe {
        #[arg(long)]
        addr: String,
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_BENCH_PEERS))]
        subscribers: usize,
    },
    /// Latency from publishing a new 3×400 policy version to its receipt by every one of N
    /// subscribed gRPC clients (p50/p95/max).
    Broadcast {
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_BENCH_PEERS), default_value_t = 8)]
        subscribers: usize,
        /// Versions to publish.
        #[arg(long, value_parser = flags::count::<u64>(flags::MAX_VERSIONS), default_value_t = 30)]
        versions: u64,
        #[arg(long)]
        json: bool,
    },
    /// Full SAC updates per second, achieved GFLOP/s against the same-run GEMM rate, and
    /// batch-8 policy inference latency.
    Sac(SacArgs),
    /// Full TEP updates per second (F and AN losses, both Adam steps, both targets), achieved
    /// GFLOP/s against the same-run GEMM rate, and the actor-side cost of guidance with E
    /// Meta-World environments (step time with and without it, alternating rounds).
    Tep {
        #[command(flatten)]
        update: TepUpdateArgs,
        /// Environments of the guided actor.
        #[arg(long, value_parser = flags::count::<usize>(flags::MAX_ENVS), default_value_t = 8)]
        envs: usize,
        /// Task set or comma-separated task names of the actor (the one-hot spans all of them).
        #[arg(long, default_value = "mt10")]
        tasks: String,
        /// Width of every hidden layer of the actor's policy (3 layers).
        #[arg(long, value_parser = flags::count::<usize>(terl_bench::args::MAX_WIDTH), default_value_t = 400)]
        policy_hidden: usize,
        /// Skip the guidance measurement (no MuJoCo needed).
        #[arg(long)]
        no_guidance: bool,
        #[arg(long)]
        json: bool,
    },
}

/// A transport `terl bench transport` can measure beside shared memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BenchTransport {
    Zenoh,
}

/// Runs one memory probe in a fresh `terl` process, so no earlier measurement's freed pages or
/// compiled models count in (or hide) this one's RSS.
fn memory_probe_process(
    tasks: &str,
    envs: usize,
    episodes: usize,
) -> Result<terl_bench::memory::MemoryProbe> {
    use anyhow::Context;
    let exe = std::env::current_exe().context("cannot find the terl executable")?;
    let out = std::process::Command::new(&exe)
        .args(["bench", "env-memory-probe", "--tasks", tasks])
        .args([
            "--envs",
            &envs.to_string(),
            "--episodes",
            &episodes.to_string(),
        ])
        .stderr(std::process::Stdio::inherit())
        .output()
        .with_context(|| format!("cannot run {}", exe.display()))?;
    anyhow::ensure!(
        out.status.success(),
        "memory probe of {tasks} failed ({})",
        out.status
    );
    serde_json::from_slice(&out.stdout)
        .with_context(|| format!("memory probe of {tasks}: unreadable output"))
}

#[allow(clippy::too_many_lines)] // one arm per benchmark
pub fn run(cmd: BenchCommand) -> Result<ExitCode> {
    match cmd {
        BenchCommand::Env {
            tasks,
            memory: true,
            envs,
            episodes,
            ..
        } => {
            anyhow::ensure!(envs >= 2, "--envs must be at least 2 (1 vs N environments)");
            anyhow::ensure!(
                envs as u64 <= MAX_MEMORY_ENVS,
                "--envs must be at most {MAX_MEMORY_ENVS}"
            );
            let tasks = terl_runtime::resolve_tasks(&tasks)?;
            let mut per_task = Vec::with_capacity(tasks.len());
            for task in &tasks {
                let probe = memory_probe_process(task, envs, episodes)?;
                tracing::info!(
                    task,
                    mb_per_additional_env = probe.mb_per_additional_env,
                    "measured"
                );
                per_task.push(probe);
            }
            let mt10 = memory_probe_process("mt10", 1, 0)?;
            let report = terl_bench::memory::memory_report(per_task, mt10, episodes);
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::EnvMemoryProbe {
            tasks,
            envs,
            episodes,
        } => {
            let tasks = terl_runtime::resolve_tasks(&tasks)?;
            let probe = terl_bench::memory::memory_probe(&tasks, envs, episodes)?;
            println!("{}", serde_json::to_string(&probe)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Env { tasks, seconds, .. } => {
            anyhow::ensure!(
                seconds > 0.0 && seconds.is_finite(),
                "--seconds must be positive"
            );
            let tasks = terl_runtime::resolve_tasks(&tasks)?;
            let report = terl_bench::env::env_bench(&tasks, seconds)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::TransportPublish {
            connect,
            tls_ca,
            run_id,
            publishers,
            seconds,
        } => {
            netns::publish(&connect, &tls_ca, &run_id, publishers, seconds)?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::BroadcastSubscribe { addr, subscribers } => {
            netns::subscribe(&addr, subscribers)?;
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Transport {
            publishers,
            seconds,
            transport,
            netns,
            versions,
            subscribers,
            ..
        } => {
            anyhow::ensure!(
                seconds > 0.0 && seconds.is_finite(),
                "--seconds must be positive"
            );
            anyhow::ensure!(publishers >= 1, "--publishers must be at least 1");
            let one = terl_bench::transport::shm_throughput(1, seconds)?;
            let many = terl_bench::transport::shm_throughput(publishers, seconds)?;
            let grpc = terl_bench::grpc::grpc_transition_stream(seconds)?;
            let best_shm = one.transitions_per_sec.min(many.transitions_per_sec);
            let zenoh = match transport {
                Some(BenchTransport::Zenoh) => Some((
                    terl_bench::transport::throughput(
                        terl_transport::TransportKind::Zenoh,
                        1,
                        seconds,
                    )?,
                    terl_bench::transport::throughput(
                        terl_transport::TransportKind::Zenoh,
                        publishers,
                        seconds,
                    )?,
                )),
                None => None,
            };
            let across = if netns {
                anyhow::ensure!(versions >= 1, "--versions must be at least 1");
                anyhow::ensure!(subscribers >= 1, "--subscribers must be at least 1");
                let ns = netns::Namespace::create()?;
                let one = netns::transport_across(&ns, 1, seconds)?;
                let many = netns::transport_across(&ns, publishers, seconds)?;
                let broadcast = netns::broadcast_across(&ns, subscribers, versions)?;
                Some((one, many, broadcast))
            } else {
                None
            };
            let broadcast_loopback = if netns {
                Some(terl_bench::grpc::broadcast_latency(subscribers, versions)?)
            } else {
                None
            };
            let lossless = |r: &terl_bench::transport::ShmBenchReport| {
                r.lost_batches == 0 && r.out_of_order == 0
            };
            let zenoh_ok = zenoh
                .as_ref()
                .is_none_or(|(a, b)| lossless(a) && lossless(b))
                && across
                    .as_ref()
                    .is_none_or(|(a, b, _)| lossless(a) && lossless(b));
            let report = serde_json::json!({
                "zenoh_netns_1_publisher": across.as_ref().map(|z| &z.0),
                "zenoh_netns_n_publishers": across.as_ref().map(|z| &z.1),
                "grpc_broadcast_netns": across.as_ref().map(|z| &z.2),
                "grpc_broadcast_loopback": broadcast_loopback,
                "zenoh_1_publisher": zenoh.as_ref().map(|z| &z.0),
                "zenoh_n_publishers": zenoh.as_ref().map(|z| &z.1),
                "shm_1_publisher": one,
                "shm_n_publishers": many,
                "grpc_stream": grpc,
                "shm_over_grpc": best_shm / grpc.transitions_per_second,
                "zero_loss": one.lost_batches == 0 && many.lost_batches == 0
                    && one.out_of_order == 0 && many.out_of_order == 0 && zenoh_ok,
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
            let report = terl_bench::grpc::broadcast_latency(subscribers, versions)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Sac(args) => {
            let report = terl_bench::sac::sac_bench(&args.config()?)?;
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
        BenchCommand::Tep {
            update,
            envs,
            tasks,
            policy_hidden,
            no_guidance,
            ..
        } => {
            let cfg = update.config(terl_sim::OBS_DIM, terl_sim::ACTION_DIM)?;
            anyhow::ensure!(envs > 0, "--envs must be at least 1");
            anyhow::ensure!(policy_hidden > 0, "--policy-hidden must be at least 1");
            let seconds = cfg.seconds;
            let tep_cfg = cfg.tep_config()?;
            let tasks = terl_runtime::resolve_tasks(&tasks)?;
            let mut report = terl_bench::tep::tep_bench(&cfg)?;
            if !no_guidance {
                report.guidance = Some(tep::guidance_overhead(
                    &tasks,
                    envs,
                    &[policy_hidden; 3],
                    &tep_cfg,
                    seconds,
                )?);
            }
            println!("{}", serde_json::to_string_pretty(&report)?);
            Ok(ExitCode::SUCCESS)
        }
    }
}
