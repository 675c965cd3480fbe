//! `terl-selector`: parse arguments, then [`terl_selector::run`] until SIGINT/SIGTERM.

use anyhow::Context;
use clap::Parser;
use terl_selector::args::Args;

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    terl_runtime::init_tracing();
    // Before anything slow: a SIGTERM during start-up then stops the service cleanly.
    let shutdown = terl_runtime::shutdown_signal();
    let a = Args::parse();
    let run = a.service.start()?;
    let run_dir = a.service.run_dir(a.run_dir);
    let mut config = terl_selector::SelectorConfig::new(
        run,
        a.service.run_id,
        a.addr,
        a.service.num_actors,
        run_dir,
    );
    config.learner_addr = a.learner_addr;
    let cluster = &config.run.cluster;
    config.server_security = cluster.server_security(terl_runtime::token_from_env())?;
    config.client_security = cluster.client_security(terl_runtime::token_from_env())?;
    config.resume = a.resume;
    let listener = terl_wire::bind_secured(config.addr, &config.server_security)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let transport = terl_runtime::service::open_transport(
        config.run.cluster.service_transport_config(
            config.run_id.as_str(),
            config.num_actors,
            terl_runtime::token_from_env(),
        )?,
        "selector",
    )?;
    terl_selector::run(config, listener, transport, shutdown).await
}
