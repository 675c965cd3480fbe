//! `terl-actor`: parse arguments, then [`terl_actor::run`] until SIGINT/SIGTERM.

use std::path::PathBuf;

use clap::Parser;

#[derive(Debug, Parser)]
#[command(
    name = "terl-actor",
    version,
    about = "Meta-World actor of a terl cluster"
)]
struct Args {
    /// Run file (TOML), the same the learner reads.
    #[arg(long)]
    config: PathBuf,
    /// Run id: names the shared-memory services.
    #[arg(long)]
    run_id: String,
    /// This actor's id, 0..num-actors (decides its share of the tasks), or `auto`: the lowest
    /// id no live actor of the run holds, stepping every task (for the replicas of a scaled
    /// Kubernetes Deployment; `--num-actors` is then the most replicas the run takes).
    #[arg(long, value_parser = parse_actor_id, value_name = "ID|auto")]
    actor_id: ActorIdArg,
    #[arg(long, default_value_t = 1)]
    num_actors: usize,
    /// The learner's gRPC address (weights stream).
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    learner_addr: String,
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

#[derive(Debug, Clone, Copy)]
enum ActorIdArg {
    Auto,
    Id(usize),
}

fn parse_actor_id(s: &str) -> Result<ActorIdArg, String> {
    if s == "auto" {
        return Ok(ActorIdArg::Auto);
    }
    s.parse()
        .map(ActorIdArg::Id)
        .map_err(|_| format!("{s:?} is neither an actor id (0, 1, ...) nor `auto`"))
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
    let client_security = run
        .cluster
        .client_security(terl_runtime::token_from_env())?;
    let (actor_id, auto_id) = match a.actor_id {
        ActorIdArg::Auto => (0, true),
        ActorIdArg::Id(id) => (id, false),
    };
    let mut config =
        terl_actor::ActorConfig::new(run, a.run_id, actor_id, a.num_actors, a.learner_addr);
    config.auto_id = auto_id;
    config.client_security = client_security;
    let role = if auto_id {
        "actor-auto".to_owned()
    } else {
        format!("actor-{actor_id}")
    };
    let transport = terl_runtime::service::open_transport(
        config
            .run
            .cluster
            .transport_config(config.run_id.as_str(), config.num_actors),
        &role,
    )?;
    terl_actor::run(config, transport, terl_runtime::shutdown_signal()).await
}
