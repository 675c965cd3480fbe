//! The command line of `terl-selector` (clap), in the library so that tests can parse command
//! lines written in the documentation with the binary's own parser.

use std::path::PathBuf;

use clap::Parser;

/// Arguments of `terl-selector`.
#[derive(Debug, Parser)]
#[command(
    name = "terl-selector",
    version,
    about = "Episode selector of a terl cluster"
)]
pub struct Args {
    /// Run file (TOML), the same the learner reads.
    #[arg(long)]
    pub config: PathBuf,
    /// Run id: names the shared-memory services and the default run folder.
    #[arg(long)]
    pub run_id: String,
    /// gRPC listen address (port 0: any free port, written to `<run-dir>/selector.addr`).
    #[arg(long, default_value = terl_wire::DEFAULT_SELECTOR_ADDR)]
    pub addr: std::net::SocketAddr,
    /// Number of actor processes of the run (sizes the shared-memory services).
    #[arg(long, default_value_t = 1)]
    pub num_actors: usize,
    /// Run folder (default `runs/<run-id>`).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// `algorithm = "terl"`: the learner's gRPC address; PTR scoring follows its policy and
    /// critic weights.
    #[arg(long)]
    pub learner_addr: Option<String>,
    /// Continue the run in the run folder: success windows and PTR gates are rebuilt from its
    /// episode logs; new episodes, selected samples and evaluations go to new log files.
    #[arg(long)]
    pub resume: bool,
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
