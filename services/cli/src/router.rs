//! `terl zenoh-router`: Zenoh's router for a cluster whose processes run with
//! `[cluster.zenoh] mode = "client"` (the Kubernetes manifests' `terl-zenoh` Deployment), so
//! that actors, learner and selector need to know one stable address instead of each other's.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Debug, Args)]
pub struct RouterArgs {
    /// Endpoint to listen on (repeatable). Beyond a loopback address only QUIC (TLS 1.3 over
    /// UDP: `quic/0.0.0.0:7447`, with --tls-cert and --tls-key) with the run's token
    /// (TERL_TOKEN or --token-file) is accepted: every session that connects must then prove
    /// the token.
    #[arg(long, value_name = "ENDPOINT", default_value = "tcp/127.0.0.1:7447")]
    listen: Vec<String>,
    /// File holding the run's token (the run file's cluster.token_file); the TERL_TOKEN
    /// environment variable wins over it.
    #[arg(long, value_name = "FILE")]
    token_file: Option<std::path::PathBuf>,
    /// The run whose keys the router carries (`terl/<run id>/**`, and it answers for the run's
    /// actor-id claims); without it, every run's `terl/**`. Nothing else is routed.
    #[arg(long, value_name = "ID")]
    run_id: Option<String>,
    /// Certificate chain (PEM) presented on `quic/` endpoints (the run's cluster.tls_cert;
    /// `terl certs` makes it).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    tls_cert: Option<std::path::PathBuf>,
    /// Private key of --tls-cert (PEM; the run's cluster.tls_key).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    tls_key: Option<std::path::PathBuf>,
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
        tls: terl_transport::ZenohTls {
            ca: None,
            cert: args.tls_cert,
            key: args.tls_key,
        },
    };
    let router = terl_transport::ZenohRouter::open(&config, args.run_id.as_deref())
        .context("cannot start the router")?;
    eprintln!(
        "zenoh router {} listening on {}, carrying {}{}",
        router.session().zid(),
        config.listen.join(", "),
        args.run_id.as_deref().map_or_else(
            || "every run's keys".to_string(),
            |r| format!("run {r}'s keys")
        ),
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
