//! `terl-actor`: parse arguments, then [`terl_actor::run`] until SIGINT/SIGTERM.

use clap::Parser;
use terl_actor::args::{ActorIdArg, Args};

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    terl_runtime::init_tracing();
    // Before anything slow: a SIGTERM during start-up then stops the service cleanly.
    let shutdown = terl_runtime::shutdown_signal();
    let a = Args::parse();
    let run = a.service.start()?;
    let client_security = run
        .cluster
        .client_security(terl_runtime::token_from_env())?;
    let (actor_id, auto_id) = match a.actor_id {
        ActorIdArg::Auto => (0, true),
        ActorIdArg::Id(id) => (id, false),
    };
    let mut config = terl_actor::ActorConfig::new(
        run,
        a.service.run_id,
        actor_id,
        a.service.num_actors,
        a.learner_addr,
    );
    config.auto_id = auto_id;
    config.client_security = client_security;
    let role = if auto_id {
        "actor-auto".to_owned()
    } else {
        format!("actor-{actor_id}")
    };
    let transport = terl_runtime::service::open_transport(
        config.run.cluster.service_transport_config(
            config.run_id.as_str(),
            config.num_actors,
            terl_runtime::token_from_env(),
        )?,
        &role,
    )?;
    terl_actor::run(config, transport, shutdown).await
}
