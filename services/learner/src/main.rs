//! `terl-learner`: parse arguments, check the networks fit a message, listen, open the run's
//! transport, then [`terl_learner::run`] until SIGINT/SIGTERM.

use anyhow::Context;
use clap::Parser;
use terl_learner::args::Args;

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    terl_runtime::init_tracing();
    // Before anything slow: a SIGTERM during start-up then stops the service cleanly.
    let shutdown = terl_runtime::shutdown_signal();
    let a = Args::parse();
    let run = a.service.start()?;
    let run_dir = a.service.run_dir(a.run_dir);
    let mut config = terl_learner::LearnerConfig::new(
        run,
        a.service.run_id,
        a.addr,
        a.service.num_actors,
        run_dir,
    );
    config.tep_datasets = a.tep_dataset;
    config.server_security = config
        .run
        .cluster
        .server_security(terl_runtime::token_from_env())?;
    config.resume = a.resume;
    config.idle_when_finished = a.when_finished == terl_learner::args::WhenFinished::Idle;
    // Refused before listening: weights that would not fit a gRPC message.
    terl_learner::check_start_up(&config)?;
    let listener = terl_wire::bind_secured(config.addr, &config.server_security)
        .await
        .with_context(|| format!("cannot listen on {}", config.addr))?;
    let transport = terl_runtime::service::open_transport(
        config.run.cluster.service_transport_config(
            config.run_id.as_str(),
            config.num_actors,
            terl_runtime::token_from_env(),
        )?,
        "learner",
    )?;
    terl_learner::run(config, listener, transport, shutdown).await
}
