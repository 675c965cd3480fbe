//! `terl`: the command line of the terl system. The binary is `src/main.rs`; the parser and
//! the subcommands live in this library so that tests can parse the command lines written in
//! the documentation with the binary's own parser ([`Cli`]).

#![warn(missing_docs)]

mod bench;
mod certs;
mod cluster;
mod env;
mod eval;
mod folder_lock;
mod font;
mod planner;
mod render;
mod report;
mod router;
mod status;
mod train;

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Arguments of `terl`.
#[derive(Debug, Parser)]
#[command(
    name = "terl",
    version,
    about = "Multi-task robot-manipulation RL on Meta-World v3"
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// The subcommands of `terl`.
#[derive(Debug, Subcommand)]
enum Command {
    /// Meta-World tasks: list, replay traces, compare traces.
    #[command(subcommand)]
    Env(env::EnvCommand),
    /// Benchmarks (JSON output).
    #[command(subcommand)]
    Bench(bench::BenchCommand),
    /// Deterministic evaluation of a checkpoint on each task's 50 goal variations (success
    /// rate, return, first-success step per task; MT-Test zero-shot tasks too).
    Eval(eval::EvalArgs),
    /// Videos of a checkpoint's evaluation episodes (MP4 and a PNG strip per task and goal
    /// variation), rendered offscreen by MuJoCo from a named camera.
    Render(render::RenderArgs),
    /// Single-process training (Meta-World envs + MTSAC in one process).
    Train(train::TrainArgs),
    /// Status of a running cluster (learner and selector).
    Status(status::StatusArgs),
    /// The local cluster: up (the launcher deploy/local-cluster.sh runs), down and clean.
    #[command(subcommand)]
    Cluster(cluster::ClusterCommand),
    /// Reports of runs: final evaluation success over seeds next to the paper's Table I,
    /// per-task breakdown and learning curves (results.md, PNG/SVG), and each cluster run's
    /// training-episode table (report.md, learning-curves.svg).
    Report(report::ReportArgs),
    /// The planner offline: datasets from scripted policies, training, and evaluation against
    /// true step gaps and in the real environment.
    #[command(subcommand)]
    Planner(planner::PlannerCommand),
    /// TLS files for a run's gRPC control plane: a fresh CA, one certificate it signs for the
    /// given hosts and its key; prints the run-file settings that use them.
    Certs(certs::CertsArgs),
    /// Zenoh's router, for clusters whose processes run with `[cluster.zenoh] mode = "client"`
    /// (e.g. the Kubernetes manifests in deploy/k8s); stops on SIGINT/SIGTERM.
    ZenohRouter(router::RouterArgs),
}

/// Runs the parsed command line; the exit code on success (some subcommands report a
/// failed check with code 1 without an error).
///
/// # Errors
/// The subcommand's error, printed by the binary as `error: …` with exit code 1.
pub fn run(cli: Cli) -> Result<std::process::ExitCode> {
    match cli.command {
        Command::Env(c) => env::run(c),
        Command::Bench(c) => bench::run(c),
        Command::Train(a) => train::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Render(a) => render::run(a),
        Command::Status(a) => status::run(a),
        Command::Cluster(c) => cluster::run(c),
        Command::Report(a) => report::run(a),
        Command::Planner(c) => planner::run(c),
        Command::Certs(a) => certs::run(a),
        Command::ZenohRouter(a) => router::run(a),
    }
}
