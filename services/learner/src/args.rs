//! The command line of `terl-learner` (clap), in the library so that tests can parse command
//! lines written in the documentation with the binary's own parser.

use std::path::PathBuf;

use clap::Parser;

/// What a learner does once its run is finished (`--when-finished`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum WhenFinished {
    /// Exit with code 0.
    Exit,
    /// Keep answering status until stopped.
    Idle,
}

/// Arguments of `terl-learner`.
#[derive(Debug, Parser)]
#[command(
    name = "terl-learner",
    version,
    about = "MTSAC learner of a terl cluster"
)]
pub struct Args {
    /// The flags every service takes (run file, run id, actor count, parent, Zenoh endpoints).
    #[command(flatten)]
    pub service: terl_runtime::service::ServiceArgs,
    /// gRPC listen address (port 0: any free port, written to `<run-dir>/learner.addr`).
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    pub addr: std::net::SocketAddr,
    /// Run folder (default `runs/<run-id>`).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// `algorithm = "terl"`: start the TEP buffer from this dataset (an earlier run's
    /// `runs/<id>/tep-dataset.mcap`); repeat the flag to load several, in order.
    #[arg(long)]
    pub tep_dataset: Vec<PathBuf>,
    /// Continue the run in the run folder from its newest intact checkpoint (networks, targets,
    /// optimisers, per-task α, counters, generators, planner; the TEP buffer from the run's
    /// tep-dataset files). Damaged checkpoints are skipped with a warning; a run without any
    /// checkpoint starts fresh. The replay buffer refills with warmup_env_steps fresh
    /// transitions before updates continue.
    #[arg(long)]
    pub resume: bool,
    /// What the learner does once the run is finished (its train.total_env_steps reached, now
    /// or by an earlier process of the run found with --resume): `exit` with code 0 (what the
    /// local launcher expects), or `idle`: keep answering status until SIGTERM, writing nothing
    /// more, for supervisors that restart a process that exits (a Kubernetes Deployment); a
    /// learner that reached the budget itself also keeps streaming its last weights. A resumed
    /// run that is already finished (its budget; a stage-1 planner-sample stop is not detected)
    /// writes no file either way.
    #[arg(long, value_enum, default_value_t = WhenFinished::Exit)]
    pub when_finished: WhenFinished,
}
