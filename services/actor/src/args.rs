//! The command line of `terl-actor` (clap), in the library so that tests can parse command
//! lines written in the documentation with the binary's own parser.

use clap::Parser;

/// Arguments of `terl-actor`.
#[derive(Debug, Parser)]
#[command(
    name = "terl-actor",
    version,
    about = "Meta-World actor of a terl cluster"
)]
pub struct Args {
    /// The flags every service takes (run file, run id, actor count, parent, Zenoh endpoints).
    #[command(flatten)]
    pub service: terl_runtime::service::ServiceArgs,
    /// This actor's id, 0..num-actors (decides its share of the tasks), or `auto`: the lowest
    /// id no live actor of the run holds, stepping every task (for the replicas of a scaled
    /// Kubernetes Deployment; `--num-actors` is then the most replicas the run takes).
    #[arg(long, value_parser = parse_actor_id, value_name = "ID|auto")]
    pub actor_id: ActorIdArg,
    /// The learner's gRPC address (weights stream).
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    pub learner_addr: String,
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
    match s.parse::<usize>() {
        Ok(id) if (id as u64) < terl_runtime::flags::MAX_ACTORS => Ok(ActorIdArg::Id(id)),
        Ok(_) => Err(format!(
            "an actor id must be below {} (the most actors a run takes), or `auto`",
            terl_runtime::flags::MAX_ACTORS
        )),
        Err(_) => Err(format!(
            "{s:?} is neither an actor id (0, 1, ...) nor `auto`"
        )),
    }
}
