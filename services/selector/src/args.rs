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
    /// The flags every service takes (run file, run id, actor count, parent, Zenoh endpoints).
    #[command(flatten)]
    pub service: terl_runtime::service::ServiceArgs,
    /// gRPC listen address (port 0: any free port, written to `<run-dir>/selector.addr`).
    #[arg(long, default_value = terl_wire::DEFAULT_SELECTOR_ADDR)]
    pub addr: std::net::SocketAddr,
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
}
