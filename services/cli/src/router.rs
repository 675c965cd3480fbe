//! `terl zenoh-router`: Zenoh's router for a cluster whose processes run with
//! `[cluster.zenoh] mode = "client"` (the Kubernetes manifests' `terl-zenoh` Deployment), so
//! that actors, learner and selector need to know one stable address instead of each other's.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct RouterArgs {
    /// Endpoint to listen on (repeatable).
    #[arg(long, value_name = "ENDPOINT", default_value = "tcp/0.0.0.0:7447")]
    listen: Vec<String>,
    /// Also find peers by UDP multicast on the local network.
    #[arg(long)]
    multicast_scouting: bool,
}

/// Runs the router until SIGINT or SIGTERM.
pub fn run(args: RouterArgs) -> Result<ExitCode> {
    let config = terl_transport::ZenohConfig {
        mode: terl_transport::ZenohMode::Router,
        listen: args.listen,
        connect: vec![],
        multicast_scouting: args.multicast_scouting,
    };
    let router = terl_transport::ZenohRouter::open(&config).context("cannot start the router")?;
    eprintln!(
        "zenoh router {} listening on {}",
        router.session().zid(),
        config.listen.join(", ")
    );
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?
        .block_on(async { terl_runtime::shutdown_signal().await });
    eprintln!("zenoh router stopped");
    Ok(ExitCode::SUCCESS)
}
