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
    /// Run file (TOML), e.g. deploy/configs/mt10.toml.
    #[arg(long)]
    pub config: PathBuf,
    /// Run id: names the shared-memory services and the default run folder.
    #[arg(long)]
    pub run_id: String,
    /// gRPC listen address (port 0: any free port, written to `<run-dir>/learner.addr`).
    #[arg(long, default_value = terl_wire::DEFAULT_LEARNER_ADDR)]
    pub addr: std::net::SocketAddr,
    /// Number of actor processes (sizes the shared-memory services).
    #[arg(long, default_value_t = 1)]
    pub num_actors: usize,
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
