//! `terl zenoh-router`: Zenoh's router for a cluster whose processes run with
//! `[cluster.zenoh] mode = "client"` (the Kubernetes manifests' `terl-zenoh` Deployment), so
//! that actors, learner and selector need to know one stable address instead of each other's.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct RouterArgs {
    /// Endpoint to listen on (repeatable). Any but a loopback address needs the run's token
    /// (TERL_TOKEN or --token-file): every session that connects must then prove it.
    #[arg(long, value_name = "ENDPOINT", default_value = "tcp/127.0.0.1:7447")]
    listen: Vec<String>,
    /// File holding the run's token (the run file's cluster.token_file); the TERL_TOKEN
    /// environment variable wins over it.
    #[arg(long, value_name = "FILE")]
    token_file: Option<std::path::PathBuf>,
}

/// Runs the router until SIGINT or SIGTERM.
pub fn run(args: RouterArgs) -> Result<ExitCode> {
    let token = match (terl_runtime::token_from_env(), &args.token_file) {
        (Some(value), _) => Some(terl_wire::Token::new(value, terl_wire::TOKEN_ENV)?),
        (None, Some(path)) => Some(terl_wire::Token::from_file(path).context("--token-file")?),
        (None, None) => None,
    };
    let secret = token
        .map(|t| terl_transport::ZenohSecret::new(t.expose()))
        .transpose()?;
    let config = terl_transport::ZenohConfig {
        mode: terl_transport::ZenohMode::Router,
        listen: args.listen,
        connect: vec![],
        multicast_scouting: false,
        secret,
    };
    let router = terl_transport::ZenohRouter::open(&config).context("cannot start the router")?;
    eprintln!(
        "zenoh router {} listening on {}{}",
        router.session().zid(),
        config.listen.join(", "),
        if config.secret.is_some() {
            " (sessions authenticate with the run's token)"
        } else {
            ""
        }
    );
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?
        .block_on(async { terl_runtime::shutdown_signal().await });
    eprintln!("zenoh router stopped");
    Ok(ExitCode::SUCCESS)
}
