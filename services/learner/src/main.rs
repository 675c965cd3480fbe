//! `terl-learner`: parse arguments, check the networks fit a message, listen, open the run's
//! transport, then [`terl_learner::run`] until SIGINT/SIGTERM.

use std::path::PathBuf;

use anyhow::Context;
use clap::Parser;

#[derive(Debug, Parser)]
#[command(
    name = "terl-learner",
    version,
    about = "MTSAC learner of a terl cluster"
)]
struct Args {
    /// Run file (TOML), e.g. deploy/configs/mt10.toml.
    #[arg(long)]
    config: PathBuf,
    /// Run id: names the shared-memory services and the default run folder.
    #[arg(long)]
    run_id: String,
    /// gRPC listen address (port 0: any free port, written to <run-dir>/learner.addr).
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    addr: std::net::SocketAddr,
    /// Number of actor processes (sizes the shared-memory services).
    #[arg(long, default_value_t = 1)]
    num_actors: usize,
    /// Run folder (default runs/<run-id>).
    #[arg(long)]
    run_dir: Option<PathBuf>,
    /// `algorithm = "terl"`: start the TEP buffer from this dataset (an earlier run's
    /// `runs/<id>/tep-dataset.mcap`); repeat the flag to load several, in order.
    #[arg(long)]
    tep_dataset: Vec<PathBuf>,
    /// Continue the run in the run folder from its newest intact checkpoint (networks, targets,
    /// optimisers, per-task α, counters, generators, planner; the TEP buffer from the run's
    /// tep-dataset files). Damaged checkpoints are skipped with a warning; a run without any
    /// checkpoint starts fresh. The replay buffer refills with warmup_env_steps fresh
    /// transitions before updates continue.
    #[arg(long)]
    resume: bool,
    /// Stop (as on SIGTERM) when the process with this pid, the launcher, exits or is killed:
    /// no orphans (deploy/local-cluster.sh passes its own pid).
    #[arg(long)]
    parent_pid: Option<u32>,
    /// With `[cluster] transport = "zenoh"`: a Zenoh endpoint to listen on, e.g.
    /// `tcp/0.0.0.0:7447` (repeatable; replaces the run file's `[cluster.zenoh] listen`).
    #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
    zenoh_listen: Vec<String>,
    /// With `[cluster] transport = "zenoh"`: a Zenoh endpoint to connect to, e.g. the
    /// learner host's `tcp/10.0.0.1:7447` (repeatable; replaces `[cluster.zenoh] connect`).
    #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
    zenoh_connect: Vec<String>,
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    terl_runtime::init_tracing();
    let a = Args::parse();
    if let Some(pid) = a.parent_pid {
        terl_runtime::exit_with_parent(pid)?;
    }
    let mut run = terl_runtime::RunConfig::load(&a.config)?;
    run.override_zenoh_endpoints(a.zenoh_listen, a.zenoh_connect);
    let run_dir = a
        .run_dir
        .unwrap_or_else(|| PathBuf::from("runs").join(&a.run_id));
    let mut config = terl_learner::LearnerConfig::new(run, a.run_id, a.addr, a.num_actors, run_dir);
    config.tep_datasets = a.tep_dataset;
    config.server_security = config
        .run
        .cluster
        .server_security(terl_runtime::token_from_env())?;
    config.resume = a.resume;
    // Refused before listening: weights that would not fit a gRPC message.
    terl_learner::check_start_up(&config)?;
    let listener = terl_wire::bind_secured(config.addr, &config.server_security)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let transport = terl_runtime::service::open_transport(
        config
            .run
            .cluster
            .transport_config(config.run_id.as_str(), config.num_actors),
        "learner",
    )?;
    terl_learner::run(config, listener, transport, terl_runtime::shutdown_signal()).await
}
