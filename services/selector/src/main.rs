//! `terl-selector`: parse arguments, then [`terl_selector::run`] until SIGINT/SIGTERM.

use std::path::PathBuf;

use anyhow::Context;
use clap::Parser;

#[derive(Debug, Parser)]
#[command(
    name = "terl-selector",
    version,
    about = "Episode selector of a terl cluster"
)]
struct Args {
    /// Run file (TOML), the same the learner reads.
    #[arg(long)]
    config: PathBuf,
    /// Run id: names the shared-memory services and the default run folder.
    #[arg(long)]
    run_id: String,
    /// gRPC listen address (port 0: any free port, written to <run-dir>/selector.addr).
    #[arg(long, default_value = terl_wire::DEFAULT_SELECTOR_ADDR)]
    addr: std::net::SocketAddr,
    #[arg(long, default_value_t = 1)]
    num_actors: usize,
    /// Run folder (default runs/<run-id>).
    #[arg(long)]
    run_dir: Option<PathBuf>,
    /// `algorithm = "terl"`: the learner's gRPC address; PTR scoring follows its policy and
    /// critic weights.
    #[arg(long)]
    learner_addr: Option<String>,
    /// Continue the run in the run folder: success windows and PTR gates are rebuilt from its
    /// episode logs; new episodes, selected samples and evaluations go to new log files.
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

#[tokio::main(flavor = "current_thread")]
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
    let mut config =
        terl_selector::SelectorConfig::new(run, a.run_id, a.addr, a.num_actors, run_dir);
    config.learner_addr = a.learner_addr;
    let cluster = &config.run.cluster;
    config.server_security = cluster.server_security(terl_runtime::token_from_env())?;
    config.client_security = cluster.client_security(terl_runtime::token_from_env())?;
    config.resume = a.resume;
    let listener = terl_wire::bind_secured(config.addr, &config.server_security)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let transport = terl_runtime::service::open_transport(
        config
            .run
            .cluster
            .transport_config(config.run_id.as_str(), config.num_actors),
        "selector",
    )?;
    terl_selector::run(config, listener, transport, terl_runtime::shutdown_signal()).await
}
