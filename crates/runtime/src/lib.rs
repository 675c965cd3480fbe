//! What the single-process trainer, the cluster services (learner, actors, selector) and the
//! CLI share: the run file ([`RunConfig`], including its `[cluster]` section) and the
//! Meta-World adapter behind the trainer's environment seam ([`MetaWorldVec`]), and the
//! deterministic evaluation over each task's goal variations ([`eval`]) that `terl eval` and the
//! cluster's in-run evaluator share.
//!
//! It exists so the four binaries read one schema and step environments one way, instead of
//! each carrying a copy.

#![warn(missing_docs)]

mod config;
pub mod eval;
pub mod flags;
pub mod lockstep;
mod metaworld_vec;
pub mod process;
pub mod service;

pub use config::{
    parse_seconds, token_from_env, Algorithm, ClusterConfig, OnCheckpointError, RunConfig,
    MAX_BATCH_SIZE, MAX_BUFFER_BATCHES, MAX_EPISODE_COUNT, MAX_EVAL_THREADS,
    MAX_LEARNER_CALIBRATE_SECS, MAX_NUM_ENVS, MAX_POLICY_LAG_ROUNDS, MAX_REPLAY_CAPACITY_PER_TASK,
    MAX_REPLAY_TRANSITIONS, MAX_SECONDS,
};
pub use lockstep::Lockstep;
pub use metaworld_vec::MetaWorldVec;

/// What a cluster service (learner or selector) needs to start.
#[derive(Debug, Clone)]
pub struct ServiceConfig {
    /// The run file.
    pub run: RunConfig,
    /// The run's id: names its shared-memory services (`terl/<run_id>/...`) and appears in logs.
    pub run_id: String,
    /// gRPC listen address; port 0 picks a free port (see `<run_dir>/<service>.addr`).
    pub addr: std::net::SocketAddr,
    /// Actor processes that will connect (sizes the shared-memory services).
    pub num_actors: usize,
    /// `runs/<run-id>`: checkpoints, the address file.
    pub run_dir: std::path::PathBuf,
    /// Selector with `algorithm = "terl"`: the learner whose weight stream (policy and critics)
    /// the PTR scoring follows.
    pub learner_addr: Option<String>,
    /// Learner with `algorithm = "terl"`: TEP datasets (MCAP) to load into the TEP buffer at
    /// start-up, in order, e.g. `runs/<older-run>/tep-dataset.mcap` of each MT1-Ind run.
    pub tep_datasets: Vec<std::path::PathBuf>,
    /// Token and TLS of this service's gRPC server (default: none, loopback only); the binaries
    /// fill it from `[cluster]` and `TERL_TOKEN` ([`ClusterConfig::server_security`]).
    pub server_security: terl_wire::ServerSecurity,
    /// Token and TLS trust of this service's clients (the selector's learner subscription);
    /// [`ClusterConfig::client_security`].
    pub client_security: terl_wire::ClientSecurity,
    /// Continue the run in `run_dir` from its newest intact checkpoint (learner), or from its
    /// logs (selector) instead of starting fresh.
    pub resume: bool,
    /// Learner: once the run is finished (its budget reached, now or by an earlier process of
    /// the run), keep answering status over gRPC until stopped instead of exiting, and write
    /// nothing more. For supervisors that restart a process that exits, such as a Kubernetes
    /// Deployment (`terl-learner --when-finished idle`). Default: false (exit 0).
    pub idle_when_finished: bool,
}

impl ServiceConfig {
    /// A config with the given required fields and defaults for the rest: no learner address, no
    /// TEP datasets, no token or TLS, a fresh (not resumed) run.
    pub fn new(
        run: RunConfig,
        run_id: String,
        addr: std::net::SocketAddr,
        num_actors: usize,
        run_dir: std::path::PathBuf,
    ) -> Self {
        Self {
            run,
            run_id,
            addr,
            num_actors,
            run_dir,
            learner_addr: None,
            tep_datasets: Vec::new(),
            server_security: terl_wire::ServerSecurity::default(),
            client_security: terl_wire::ClientSecurity::default(),
            resume: false,
            idle_when_finished: false,
        }
    }
}

/// Task names of a task spec: a task set (`mt10`, `mt1-ind`, ...) or comma-separated names,
/// in order; task ids everywhere are positions in this list. A task named twice is an error.
pub fn resolve_tasks(spec: &str) -> anyhow::Result<Vec<&'static str>> {
    let mut out: Vec<&'static str> = Vec::new();
    for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        for task in terl_sim::metaworld::task_set(part)? {
            // A task twice would get two one-hot slots (two policies' worth of conditioning
            // for one task) and be evaluated twice: refuse it.
            anyhow::ensure!(
                !out.contains(&task),
                "task {task} appears twice in \"{spec}\" (a task set already includes it?)"
            );
            out.push(task);
        }
    }
    anyhow::ensure!(!out.is_empty(), "no tasks given");
    Ok(out)
}

/// Completes on the first SIGINT or SIGTERM: the shutdown future every service `main` passes
/// to its `run`. The handlers are installed when this is called, not when the future is first
/// polled, so a service calls it first thing: a signal that arrives during its start-up
/// (compiling scenes, opening the transport) is then kept and stops the service as soon as its
/// loop begins, instead of killing it with the default action (exit 143). Must be called
/// inside a tokio runtime.
pub fn shutdown_signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    use tokio::signal::unix::{signal, SignalKind};
    let term = signal(SignalKind::terminate());
    let int = signal(SignalKind::interrupt());
    async move {
        match (term, int) {
            (Ok(mut term), Ok(mut int)) => tokio::select! {
                _ = int.recv() => tracing::info!("SIGINT: shutting down"),
                _ = term.recv() => tracing::info!("SIGTERM: shutting down"),
            },
            (Err(e), _) | (_, Err(e)) => {
                tracing::warn!(
                    "cannot listen for SIGTERM/SIGINT ({e}); only Ctrl-C stops this process"
                );
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
}

/// Writes `addr` to `<run_dir>/<service>.addr` (atomically: scripts and tests poll for the
/// file and must never read half of it), so a server bound to port 0 can be found.
pub fn write_addr_file(
    run_dir: &std::path::Path,
    service: &str,
    addr: std::net::SocketAddr,
) -> anyhow::Result<std::path::PathBuf> {
    use anyhow::Context;
    std::fs::create_dir_all(run_dir)
        .with_context(|| format!("cannot create {}", run_dir.display()))?;
    let path = run_dir.join(format!("{service}.addr"));
    let tmp = run_dir.join(format!(".{service}.addr.tmp"));
    std::fs::write(&tmp, format!("{addr}\n"))
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}

/// `--parent-pid PID` of the service binaries: the process gets SIGTERM when its parent (the
/// launcher) dies, even by `kill -9`, and so stops cleanly (final checkpoint, shared memory
/// released) instead of living on as an orphan. Linux only (`prctl(PR_SET_PDEATHSIG)`); elsewhere
/// a no-op with a warning.
///
/// # Errors
/// The parent is not `parent` any more (it died before this call: the process must not start),
/// or the kernel refused the setting.
pub fn exit_with_parent(parent: u32) -> anyhow::Result<()> {
    #[cfg(target_os = "linux")]
    {
        nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGTERM)
            .map_err(|e| anyhow::anyhow!("cannot ask for SIGTERM on the launcher's exit: {e}"))?;
        let now = std::os::unix::process::parent_id();
        anyhow::ensure!(
            now == parent,
            "the launcher (pid {parent}) is gone (parent is now {now}); not starting"
        );
    }
    #[cfg(not(target_os = "linux"))]
    tracing::warn!(parent, "--parent-pid has no effect on this platform");
    Ok(())
}

/// This machine's host name (`gethostname(2)`; in Kubernetes the pod's name), or `"unknown"`
/// where the kernel gives none. Actors report it to the learner, which shows it in status.
pub fn host_name() -> String {
    nix::unistd::gethostname()
        .ok()
        .map(|h| h.to_string_lossy().into_owned())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "unknown".to_owned())
}

/// Zenoh logs a session's whole configuration, its authentication password (the run's token)
/// included, at debug level from this module when the session opens. Every terl process drops
/// that module's events below warn after `RUST_LOG`'s filter, whatever it asks (a directive
/// with a field filter is more specific than any directive added to it, so this is a filter
/// of its own, not a directive).
const ZENOH_SESSION_TARGET: &str = "zenoh::api::session";

fn zenoh_session_capped(meta: &tracing::Metadata<'_>) -> bool {
    !meta.target().starts_with(ZENOH_SESSION_TARGET)
        || matches!(*meta.level(), tracing::Level::ERROR | tracing::Level::WARN)
}

/// Initialises `tracing` for a service binary: `RUST_LOG` or `info`, to stderr (colours only on
/// a terminal). Log lines carry the service's span (`learner{run=..}`, `selector{run=..}`,
/// `actor{id=..}`) before the message.
pub fn init_tracing() {
    init_tracing_with_default("info");
}

/// [`init_tracing`] with another default filter when `RUST_LOG` is unset (the `terl` command
/// line: `warn`). Does nothing when a subscriber is already set.
pub fn init_tracing_with_default(default_filter: &str) {
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    use tracing_subscriber::Layer as _;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    let layer = tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        // A log write that fails (a full disk under the run folder's log) is dropped: the
        // default reports it with `eprint!`, which panics when stderr is that same file.
        .log_internal_errors(false)
        // Plain text when logs go to a file (the launcher writes runs/<id>/*.log).
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_filter(filter)
        .with_filter(tracing_subscriber::filter::filter_fn(zenoh_session_capped));
    let _ = tracing_subscriber::registry().with(layer).try_init();
}
