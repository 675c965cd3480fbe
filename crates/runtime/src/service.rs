//! The skeleton the three cluster services share: announce the already-bound gRPC listener
//! (address file under the run folder), run the CPU-bound work on its own thread inside the
//! service's tracing span, serve until the shutdown future completes or the work stops, then
//! stop and join the work.
//!
//! The binaries bind ([`terl_wire::bind_secured`]) and open their transport; tests bind
//! `127.0.0.1:0` and hand every service of a cluster the same in-memory bus.

use std::future::Future;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::Context;
use tokio::net::TcpListener;
use tracing::Instrument;

/// The flags every cluster service takes (`terl-learner`, `terl-selector`, `terl-actor`),
/// flattened into each service's own arguments.
#[derive(Debug, Clone, clap::Args)]
pub struct ServiceArgs {
    /// Run file (TOML), e.g. deploy/configs/mt10.toml; every service of a run reads the same.
    #[arg(long)]
    pub config: PathBuf,
    /// Run id: names the shared-memory services and the default run folder (1 to 64
    /// characters of `[A-Za-z0-9._-]`, not `.` or `..`).
    #[arg(long, value_parser = parse_run_id)]
    pub run_id: String,
    /// Number of actor processes of the run (sizes the shared-memory services).
    #[arg(long, value_parser = crate::flags::count::<usize>(crate::flags::MAX_ACTORS), default_value_t = 1)]
    pub num_actors: usize,
    /// Stop (as on SIGTERM) when the process with this pid, the launcher, exits or is killed:
    /// no orphans (deploy/local-cluster.sh passes its own pid).
    #[arg(long, value_parser = crate::flags::count::<u32>(crate::flags::MAX_PID))]
    pub parent_pid: Option<u32>,
    /// With `[cluster] transport = "zenoh"`: a Zenoh endpoint to listen on, e.g.
    /// `quic/0.0.0.0:7447` (repeatable; replaces the run file's `[cluster.zenoh] listen`).
    /// Beyond loopback only `quic/` (TLS 1.3 over UDP) is accepted, with the run's token
    /// (TERL_TOKEN or the run file's `cluster.token_file`) and `[cluster] tls_cert`/`tls_key`.
    #[arg(long = "zenoh-listen", value_name = "ENDPOINT")]
    pub zenoh_listen: Vec<String>,
    /// With `[cluster] transport = "zenoh"`: a Zenoh endpoint to connect to, e.g. the
    /// learner host's `quic/10.0.0.1:7447` (repeatable; replaces `[cluster.zenoh] connect`;
    /// `quic/` needs the run's token and `[cluster] tls_ca`).
    #[arg(long = "zenoh-connect", value_name = "ENDPOINT")]
    pub zenoh_connect: Vec<String>,
}

impl ServiceArgs {
    /// A service's start: stop with the parent (`--parent-pid`), then the run file with the
    /// command line's Zenoh endpoints in place of its own.
    ///
    /// # Errors
    /// The parent watch cannot be set up, or the run file cannot be read or is invalid
    /// ([`crate::RunConfig::load`]).
    pub fn start(&self) -> anyhow::Result<crate::RunConfig> {
        if let Some(pid) = self.parent_pid {
            crate::exit_with_parent(pid)?;
        }
        let mut run = crate::RunConfig::load(&self.config)?;
        run.override_zenoh_endpoints(self.zenoh_listen.clone(), self.zenoh_connect.clone());
        Ok(run)
    }

    /// The run folder: `flag` (`--run-dir`) when given, else `runs/<run-id>`.
    pub fn run_dir(&self, flag: Option<PathBuf>) -> PathBuf {
        flag.unwrap_or_else(|| PathBuf::from("runs").join(&self.run_id))
    }
}

/// Opens the run's transport for `role` (`learner`, `selector`, `actor-3`) with `config`, on a
/// plain thread outside the caller's async runtime: Zenoh's blocking calls refuse to run on
/// a tokio current-thread runtime, which the selector and actor binaries use. Blocks the
/// caller until opened (start-up only).
///
/// # Errors
/// The transport cannot be opened (see [`terl_transport::RunTransport::open`]).
pub fn open_transport(
    config: terl_transport::TransportConfig,
    role: &str,
) -> anyhow::Result<terl_transport::RunTransport> {
    std::thread::scope(|s| {
        s.spawn(|| terl_transport::RunTransport::open(config, role))
            .join()
            .map_err(|_| anyhow::anyhow!("opening the transport panicked"))?
            .map_err(anyhow::Error::from)
    })
}

/// Writes `<run_dir>/<service>.addr` for the listener's address and logs
/// "`<service>` listening"; the address and the file.
///
/// # Errors
/// The listener has no local address, or the file cannot be written.
pub fn announce(
    listener: &TcpListener,
    run_dir: &Path,
    service: &str,
    run_id: &str,
) -> anyhow::Result<(SocketAddr, PathBuf)> {
    let addr = listener.local_addr()?;
    let file = crate::write_addr_file(run_dir, service, addr)?;
    tracing::info!(%addr, file = %file.display(), run_id, "{service} listening");
    Ok((addr, file))
}

/// A service's CPU-bound loop on its own named thread, inside a tracing span.
#[derive(Debug)]
pub struct Worker {
    /// What the logs and errors call it ("trainer thread", "episode receiver", ...).
    what: String,
    handle: std::thread::JoinHandle<anyhow::Result<()>>,
    done: tokio::sync::watch::Receiver<bool>,
}

impl Worker {
    /// Starts `work` on a thread named `thread` inside `span`. `what` names it in logs and in
    /// the error when it panics.
    ///
    /// # Errors
    /// The thread cannot be spawned.
    pub fn spawn(
        thread: &str,
        what: &str,
        span: tracing::Span,
        work: impl FnOnce() -> anyhow::Result<()> + Send + 'static,
    ) -> anyhow::Result<Self> {
        let (done_tx, done) = tokio::sync::watch::channel(false);
        let handle = std::thread::Builder::new()
            .name(thread.into())
            .spawn(move || {
                let result = span.in_scope(work);
                let _ = done_tx.send(true);
                result
            })
            .with_context(|| format!("cannot start the {what}"))?;
        Ok(Self {
            what: what.to_owned(),
            handle,
            done,
        })
    }

    /// Completes once the work has returned (or panicked).
    pub async fn stopped(&mut self) {
        // An error means the sender is gone: the thread ended (a panic unwinds past the send).
        let _ = self.done.wait_for(|done| *done).await;
    }

    /// Waits for the thread without blocking the runtime; the work's result.
    ///
    /// # Errors
    /// The work's error, or "`<what>` panicked".
    pub async fn join(self) -> anyhow::Result<()> {
        let what = self.what;
        let handle = self.handle;
        tokio::task::spawn_blocking(move || handle.join())
            .await?
            .map_err(|_| anyhow::anyhow!("{what} panicked"))?
    }
}

/// The future that ends a gRPC server (see [`serve_until`]).
pub type StopServing<'a> = std::pin::Pin<Box<dyn Future<Output = ()> + Send + 'a>>;

/// Serves until `shutdown` completes or `worker` stops (logged), whichever is first:
/// `serve` gets the future that ends serving. Returns what `serve` returned; the caller then
/// tells its worker to stop and [`Worker::join`]s it.
pub async fn serve_until<'a, F, E>(
    shutdown: impl Future<Output = ()> + Send + 'a,
    worker: &'a mut Worker,
    serve: impl FnOnce(StopServing<'a>) -> F,
) -> Result<(), E>
where
    F: Future<Output = Result<(), E>>,
{
    let what = worker.what.clone();
    let stop_serving = async move {
        tokio::select! {
            () = shutdown => {}
            () = worker.stopped() => tracing::info!("{what} stopped; shutting down"),
        }
    };
    serve(Box::pin(stop_serving.in_current_span())).await
}

/// `--run-id` as every transport checks it ([`terl_transport::TransportConfig::validate`]),
/// while clap parses: a run id that is also a run folder's name cannot leave `runs/`.
fn parse_run_id(value: &str) -> Result<String, String> {
    terl_transport::TransportConfig::new(value, 1)
        .validate()
        .map(|()| value.to_owned())
        .map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The worker's error comes back from `join`, its panic as an error naming it, and serving
    /// ends as soon as the worker stops.
    #[test]
    fn serving_ends_when_the_worker_stops_and_join_returns_its_outcome() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let mut w = Worker::spawn("w", "test worker", tracing::Span::none(), || {
                anyhow::bail!("work failed")
            })
            .unwrap();
            let served: Result<(), ()> =
                serve_until(std::future::pending(), &mut w, |stop| async move {
                    stop.await;
                    Ok(())
                })
                .await;
            assert!(served.is_ok());
            let e = w.join().await.unwrap_err().to_string();
            assert_eq!(e, "work failed");

            let w = Worker::spawn("w", "test worker", tracing::Span::none(), || panic!("boom"))
                .unwrap();
            let e = w.join().await.unwrap_err().to_string();
            assert_eq!(e, "test worker panicked");
        });
    }

    #[test]
    fn announce_writes_the_address_file() {
        let dir = tempfile::tempdir().unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
            let (addr, file) = announce(&l, dir.path(), "learner", "r").unwrap();
            assert_eq!(file, dir.path().join("learner.addr"));
            assert_eq!(std::fs::read_to_string(file).unwrap(), format!("{addr}\n"));
        });
    }
}
