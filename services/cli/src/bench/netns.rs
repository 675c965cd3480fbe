//! `terl bench transport --transport zenoh --netns`: the transition stream and the weight
//! broadcast between two network namespaces, as between two hosts. This process (the
//! learner's side) stays in the host's namespace; a namespace of its own, joined to it by a
//! veth pair (10.215.x.1 here, 10.215.x.2 there), runs the actors' side as a child process
//! (`ip netns exec ... terl bench transport-publish` / `broadcast-subscribe`). Everything
//! created is removed when the measurement ends, also on error. Needs root.

use std::io::Read;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{bail, Context, Result};
use serde::Serialize;
use terl_bench::transport::{PublishReport, ShmBenchReport};
use terl_transport::TransportError;
use terl_wire::{
    ClientOptions, ClientSecurity, ServeOptions, ServerSecurity, Token, WeightHub, WeightsKind,
};
use tokio::io::AsyncBufReadExt;

/// A network namespace and the veth pair to it; removed on drop.
pub struct Namespace {
    pub name: String,
    host_dev: String,
    pub host_ip: Ipv4Addr,
    pub ns_ip: Ipv4Addr,
}

fn ip(args: &[&str]) -> Result<()> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .context("cannot run `ip` (iproute2)")?;
    if !out.status.success() {
        bail!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

/// Namespaces of this bench are `terl-bench-<pid of the bench>`.
const NS_PREFIX: &str = "terl-bench-";

/// The host's end of the veth pair of the bench with process id `pid` (at most 15 bytes).
fn host_dev(pid: u32) -> String {
    format!("tbh{}", pid % 1_000_000)
}

/// The benches' namespaces in `ip netns list` output (`name` or `name (id: N)` per line)
/// whose process is not `alive`, with that process id.
pub fn stale_namespaces(list: &str, alive: impl Fn(u32) -> bool) -> Vec<(String, u32)> {
    list.lines()
        .filter_map(|line| line.split_whitespace().next())
        .filter_map(|name| {
            let pid = name.strip_prefix(NS_PREFIX)?.parse::<u32>().ok()?;
            (!alive(pid)).then(|| (name.to_string(), pid))
        })
        .collect()
}

/// Removes what a bench killed before it could clean up (SIGKILL, a crash) left behind: the
/// namespaces `terl-bench-<pid>` of processes that no longer run, and their veth pairs.
/// Returns the namespaces removed; each is also logged.
pub fn remove_stale() -> Vec<String> {
    let Ok(out) = Command::new("ip").args(["netns", "list"]).output() else {
        return Vec::new();
    };
    let list = String::from_utf8_lossy(&out.stdout);
    let alive = |pid: u32| std::path::Path::new(&format!("/proc/{pid}")).exists();
    let mut removed = Vec::new();
    for (name, pid) in stale_namespaces(&list, alive) {
        let _ = ip(&["link", "del", &host_dev(pid)]);
        match ip(&["netns", "del", &name]) {
            Ok(()) => {
                tracing::warn!(
                    "removed network namespace {name}, left behind by an earlier bench \
                     (process {pid}) that was killed"
                );
                removed.push(name);
            }
            Err(e) => tracing::warn!("cannot remove the stale namespace {name}: {e:#}"),
        }
    }
    removed
}

/// Until the process exits, SIGINT, SIGTERM and SIGHUP remove the namespace `name` and the
/// veth `host_dev` (whichever exist) before the process exits with 128 + the signal's
/// number, as it would have without the handler. Installed once per process.
fn remove_on_signal(name: String, host_dev: String) -> Result<()> {
    use tokio::signal::unix::{signal, SignalKind};
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<std::io::Result<()>>();
    std::thread::Builder::new()
        .name("netns-signals".into())
        .spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread()
                .enable_io()
                .build()
            {
                Ok(r) => r,
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                    return;
                }
            };
            runtime.block_on(async move {
                let kinds = [
                    (SignalKind::interrupt(), 2),
                    (SignalKind::terminate(), 15),
                    (SignalKind::hangup(), 1),
                ];
                let mut streams = Vec::new();
                for (kind, number) in kinds {
                    match signal(kind) {
                        Ok(s) => streams.push((s, number)),
                        Err(e) => {
                            let _ = ready_tx.send(Err(e));
                            return;
                        }
                    }
                }
                let _ = ready_tx.send(Ok(()));
                let received =
                    futures_util::future::select_all(streams.iter_mut().map(|(s, number)| {
                        Box::pin(async move { s.recv().await.map(|_| *number) })
                    }))
                    .await
                    .0;
                let _ = ip(&["netns", "del", &name]);
                let _ = ip(&["link", "del", &host_dev]);
                let number = received.unwrap_or(15);
                eprintln!("terl: signal {number}; removed the network namespace {name}");
                std::process::exit(128 + number);
            });
        })?;
    ready_rx
        .recv()
        .context("the signal thread ended")?
        .context("cannot install the signal handlers")?;
    Ok(())
}

impl Namespace {
    /// Creates `terl-bench-<pid>` and a veth pair to it with addresses in 10.215.x.0/24,
    /// first removing what killed benches left behind ([`remove_stale`]). From here until
    /// the process exits, SIGINT/SIGTERM/SIGHUP remove both before exiting.
    ///
    /// # Errors
    /// Namespaces cannot be made (not root, no `ip`), naming the command that failed.
    pub fn create() -> Result<Self> {
        let pid = std::process::id();
        let name = format!("{NS_PREFIX}{pid}");
        remove_stale();
        remove_on_signal(name.clone(), host_dev(pid))?;
        ip(&["netns", "add", &name]).context("creating a network namespace needs root")?;
        let octet = (1 + pid % 250) as u8;
        let ns = Self {
            name,
            host_dev: host_dev(pid),
            host_ip: Ipv4Addr::new(10, 215, octet, 1),
            ns_ip: Ipv4Addr::new(10, 215, octet, 2),
        };
        let ns_dev = format!("tbn{}", pid % 1_000_000);
        let (host_cidr, ns_cidr) = (format!("{}/24", ns.host_ip), format!("{}/24", ns.ns_ip));
        ip(&[
            "link",
            "add",
            &ns.host_dev,
            "type",
            "veth",
            "peer",
            "name",
            &ns_dev,
        ])?;
        ip(&["link", "set", &ns_dev, "netns", &ns.name])?;
        ip(&["addr", "add", &host_cidr, "dev", &ns.host_dev])?;
        ip(&["link", "set", &ns.host_dev, "up"])?;
        ip(&["-n", &ns.name, "addr", "add", &ns_cidr, "dev", &ns_dev])?;
        ip(&["-n", &ns.name, "link", "set", &ns_dev, "up"])?;
        ip(&["-n", &ns.name, "link", "set", "lo", "up"])?;
        Ok(ns)
    }

    /// `terl` with `args`, inside the namespace.
    fn terl(&self, args: &[String]) -> Result<Command> {
        // This very executable through its /proc link: it still runs when the file on disk was
        // replaced meanwhile (a rebuild), where the path would name a deleted file.
        let exe = PathBuf::from(format!("/proc/{}/exe", std::process::id()));
        anyhow::ensure!(
            exe.exists(),
            "cannot find the terl executable ({})",
            exe.display()
        );
        let mut cmd = Command::new("ip");
        cmd.args(["netns", "exec", &self.name]).arg(exe).args(args);
        Ok(cmd)
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        // Deleting the namespace deletes the veth end in it, and with it the pair.
        let _ = ip(&["netns", "del", &self.name]);
        let _ = ip(&["link", "del", &self.host_dev]);
    }
}

fn free_port(ip: Ipv4Addr) -> Result<u16> {
    Ok(std::net::TcpListener::bind((ip, 0))?.local_addr()?.port())
}

fn stderr_file(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("terl-bench-{}-{tag}.err", std::process::id()))
}

/// The transition stream from `publishers` actors' sessions in the namespace to a receiver
/// on the host side, for `seconds`.
pub fn transport_across(ns: &Namespace, publishers: usize, seconds: f64) -> Result<ShmBenchReport> {
    let endpoint = format!("quic/{}:{}", ns.host_ip, free_port(ns.host_ip)?);
    let run_id = format!("bench-netns-{}-{publishers}", std::process::id());
    // The receiver's certificate for the host side's address, as `terl certs` makes it.
    let certs = tempfile::tempdir()?;
    let files = terl_wire::certs::write_run_certificates(
        certs.path(),
        "terl bench",
        &[ns.host_ip.to_string()],
    )?;
    let tls = terl_transport::ZenohTls {
        ca: Some(files.ca.clone()),
        cert: Some(files.cert),
        key: Some(files.key),
    };
    let err_path = stderr_file(&format!("publish-{publishers}"));
    let mut child: Option<Child> = None;
    let spawn = || -> Result<Child> {
        let mut cmd = ns.terl(&[
            "bench".into(),
            "transport-publish".into(),
            "--connect".into(),
            endpoint.clone(),
            "--tls-ca".into(),
            files.ca.display().to_string(),
            "--run-id".into(),
            run_id.clone(),
            "--publishers".into(),
            publishers.to_string(),
            "--seconds".into(),
            seconds.to_string(),
        ])?;
        Ok(cmd
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&err_path)?)
            .spawn()?)
    };
    let fail = |msg: String| TransportError::Config(msg);
    let report = terl_bench::transport::zenoh_receive(
        &endpoint,
        tls,
        &run_id,
        publishers,
        "zenoh-quic-netns",
        || {
            if child.is_none() {
                child = Some(spawn().map_err(|e| fail(format!("{e:#}")))?);
            }
            let c = child.as_mut().expect("spawned");
            let Some(status) = c.try_wait().map_err(|e| fail(e.to_string()))? else {
                return Ok(None);
            };
            let mut out = String::new();
            if let Some(mut stdout) = c.stdout.take() {
                let _ = stdout.read_to_string(&mut out);
            }
            if !status.success() {
                let err = std::fs::read_to_string(&err_path).unwrap_or_default();
                return Err(fail(format!(
                    "the publishing process in {} failed ({status}): {}",
                    ns.name,
                    err.trim()
                )));
            }
            serde_json::from_str::<PublishReport>(out.trim())
                .map(Some)
                .map_err(|e| fail(format!("publisher output {out:?}: {e}")))
        },
    );
    if let Some(mut c) = child {
        let _ = c.kill();
        let _ = c.wait();
    }
    let _ = std::fs::remove_file(&err_path);
    Ok(report?)
}

/// The actors' half of [`transport_across`] (`terl bench transport-publish`, inside the
/// namespace): prints what was sent as JSON.
pub fn publish(
    connect: &str,
    ca: &Path,
    run_id: &str,
    publishers: usize,
    seconds: f64,
) -> Result<()> {
    let report = terl_bench::transport::zenoh_publish(connect, ca, run_id, publishers, seconds)?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}

/// Weight-broadcast latency between the namespaces.
#[derive(Debug, Clone, Serialize)]
pub struct RemoteBroadcastReport {
    pub transport: &'static str,
    pub subscribers: usize,
    pub versions: u64,
    pub encoded_bytes_per_version: usize,
    /// Publish (encoding and CRC included) → received, validated and decoded by each
    /// subscriber in the other namespace; wall-clock times of one kernel, one sample per
    /// (version, subscriber).
    pub samples: usize,
    pub latency_ms_p50: f64,
    pub latency_ms_p95: f64,
    pub latency_ms_max: f64,
    /// Versions a subscriber never saw because a newer one overtook it (latest-wins).
    pub skipped: u64,
}

fn unix_nanos(t: SystemTime) -> u128 {
    t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos())
}

/// A 3×400 policy published `versions` times (one at a time, each after every subscriber
/// received the previous one and 5 ms) by a learner's gRPC server on the host side (with a
/// token, as any non-loopback learner) to `subscribers` clients in the namespace.
pub fn broadcast_across(
    ns: &Namespace,
    subscribers: usize,
    versions: u64,
) -> Result<RemoteBroadcastReport> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?
        .block_on(broadcast_across_async(ns, subscribers, versions))
}

async fn broadcast_across_async(
    ns: &Namespace,
    subscribers: usize,
    versions: u64,
) -> Result<RemoteBroadcastReport> {
    let secret: String = (0..32)
        .map(|_| format!("{:x}", rand::random::<u8>() % 16))
        .collect();
    let security = ServerSecurity {
        token: Some(Token::new(secret.clone(), "bench")?),
        ..ServerSecurity::default()
    };
    let listener = terl_wire::bind_secured(SocketAddr::from((ns.host_ip, 0)), &security).await?;
    let addr = listener.local_addr()?.to_string();
    let hub = WeightHub::new();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(terl_wire::serve_learner_with(
        listener,
        terl_bench::grpc::HubOnly(hub.clone()),
        async {
            let _ = stopped.await;
        },
        ServeOptions {
            security,
            ..ServeOptions::default()
        },
    ));
    let err_path = stderr_file("subscribe");
    let mut cmd: tokio::process::Command = ns
        .terl(&[
            "bench".into(),
            "broadcast-subscribe".into(),
            "--addr".into(),
            addr,
            "--subscribers".into(),
            subscribers.to_string(),
        ])?
        .into();
    let mut child = cmd
        .env("TERL_TOKEN", &secret)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&err_path)?)
        .kill_on_drop(true)
        .spawn()?;
    let mut lines = tokio::io::BufReader::new(child.stdout.take().expect("piped")).lines();
    let result = async {
        let deadline = Instant::now() + Duration::from_secs(20);
        while hub.subscriber_count() < subscribers {
            if Instant::now() > deadline {
                let err = std::fs::read_to_string(&err_path).unwrap_or_default();
                bail!(
                    "the subscribers in {} did not connect: {}",
                    ns.name,
                    err.trim()
                );
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let prepared: Vec<_> = (1..=versions)
            .map(|v| terl_bench::grpc::policy_weights(v, &terl_bench::grpc::POLICY_LAYERS))
            .collect();
        let encoded = prepared.first().map_or(0, terl_bench::grpc::encoded_len);
        let mut latencies = Vec::new();
        let (mut skipped, mut last_seen) = (0u64, vec![0u64; subscribers]);
        for weights in prepared {
            let version = weights.version();
            let published = unix_nanos(SystemTime::now());
            hub.publish(&weights)?;
            let mut pending = subscribers;
            while pending > 0 {
                let line = tokio::time::timeout(Duration::from_secs(10), lines.next_line())
                    .await
                    .with_context(|| format!("version {version} not delivered within 10 s"))??
                    .context("the subscribing process ended")?;
                let mut f = line.split_whitespace().map(str::parse::<u128>);
                let (Some(Ok(id)), Some(Ok(got)), Some(Ok(at))) = (f.next(), f.next(), f.next())
                else {
                    bail!("subscriber printed {line:?}");
                };
                let (id, got) = (id as usize, got as u64);
                anyhow::ensure!(id < subscribers, "subscriber id {id}");
                skipped += got.saturating_sub(last_seen[id] + 1);
                last_seen[id] = got;
                if got == version {
                    latencies.push(at.saturating_sub(published) as f64 / 1e6);
                    pending -= 1;
                }
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        latencies.sort_by(f64::total_cmp);
        Ok(RemoteBroadcastReport {
            transport: "grpc-tcp-netns",
            subscribers,
            versions,
            encoded_bytes_per_version: encoded,
            samples: latencies.len(),
            latency_ms_p50: terl_bench::grpc::percentile(&latencies, 0.50),
            latency_ms_p95: terl_bench::grpc::percentile(&latencies, 0.95),
            latency_ms_max: latencies.last().copied().unwrap_or(0.0),
            skipped,
        })
    }
    .await;
    let _ = stop.send(());
    let _ = tokio::time::timeout(Duration::from_secs(10), child.wait()).await;
    let _ = child.kill().await;
    let _ = server.await;
    let _ = std::fs::remove_file(&err_path);
    result
}

/// The subscribers' half of [`broadcast_across`] (`terl bench broadcast-subscribe`, inside
/// the namespace; token from `TERL_TOKEN`): prints `<subscriber> <version> <unix nanos>` per
/// version received, until the server ends the streams.
pub fn subscribe(addr: &str, subscribers: usize) -> Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let token = terl_runtime::token_from_env()
            .map(|t| Token::new(t, terl_wire::TOKEN_ENV))
            .transpose()?;
        let options = ClientOptions::secured(ClientSecurity { token, tls: None });
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<(usize, u64, u128)>();
        let mut tasks = Vec::new();
        for id in 0..subscribers {
            let mut client = terl_wire::connect_learner_with(addr, options.clone()).await?;
            let mut stream = client.watch_weights(&[WeightsKind::Policy]).await?;
            let tx = tx.clone();
            tasks.push(tokio::spawn(async move {
                while let Some(Ok(weights)) = futures_util::StreamExt::next(&mut stream).await {
                    std::hint::black_box(weights.parameter_count());
                    let at = unix_nanos(SystemTime::now());
                    if tx.send((id, weights.version(), at)).is_err() {
                        break;
                    }
                }
            }));
        }
        drop(tx);
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        while let Some((id, version, at)) = rx.recv().await {
            writeln!(out, "{id} {version} {at}")?;
            out.flush()?;
        }
        for t in tasks {
            let _ = t.await;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stale_namespaces_are_the_benches_whose_process_is_gone() {
        let list =
            "terl-bench-12 (id: 3)\nterl-bench-40\nterl-a-12\nterl-bench-x1\nother (id: 0)\n";
        let stale = stale_namespaces(list, |pid| pid == 40);
        assert_eq!(stale, vec![("terl-bench-12".to_string(), 12)]);
        assert!(stale_namespaces(list, |_| true).is_empty());
        assert_eq!(stale_namespaces("", |_| false), vec![]);
        assert_eq!(host_dev(1_234_567), "tbh234567");
    }
}
