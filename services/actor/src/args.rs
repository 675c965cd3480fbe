//! The command line of `terl-actor` (clap), in the library so that tests can parse command
//! lines written in the documentation with the binary's own parser.

use std::path::PathBuf;

use clap::Parser;

/// Arguments of `terl-actor`.
#[derive(Debug, Parser)]
#[command(
    name = "terl-actor",
    version,
    about = "Meta-World actor of a terl cluster"
)]
pub struct Args {
    /// Run file (TOML), the same the learner reads.
    #[arg(long)]
    pub config: PathBuf,
    /// Run id: names the shared-memory services.
    #[arg(long)]
    pub run_id: String,
    /// This actor's id, 0..num-actors (decides its share of the tasks), or `auto`: the lowest
    /// id no live actor of the run holds, stepping every task (for the replicas of a scaled
    /// Kubernetes Deployment; `--num-actors` is then the most replicas the run takes).
    #[arg(long, value_parser = parse_actor_id, value_name = "ID|auto")]
    pub actor_id: ActorIdArg,
    /// Number of actor processes of the run (sizes the shared-memory services).
    #[arg(long, default_value_t = 1)]
    pub num_actors: usize,
    /// The learner's gRPC address (weights stream).
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    pub learner_addr: String,
    /// Stop (as on SIGTERM) when the process with this pid, the launcher, exits or is killed:
    /// no orphans (deploy/local-cluster.sh passes its own pid).
    #[arg(long)]
    pub parent_pid: Option<u32>,
    /// With `[cluster] transport = "zenoh"`: a Zenoh endpoint to listen on, e.g.
    /// `tcp/0.0.0.0:7447` (repeatable; replaces the run file's `[cluster.zenoh] listen`).
    #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
    pub zenoh_listen: Vec<String>,
    /// With `[cluster] transport = "zenoh"`: a Zenoh endpoint to connect to, e.g. the
    /// learner host's `tcp/10.0.0.1:7447` (repeatable; replaces `[cluster.zenoh] connect`).
    #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
}

/// The value of `--actor-id`.
#[derive(Debug, Clone, Copy)]
pub enum ActorIdArg {
    /// `auto`: the lowest id no live actor of the run holds.
    Auto,
    /// A fixed id, 0..num-actors.
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
