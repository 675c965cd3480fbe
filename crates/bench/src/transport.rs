//! Throughput of the transition stream over shared memory (and over Zenoh on loopback TCP,
//! [`throughput`]), for `terl bench transport`.
//!
//! `publishers` threads, each with its own iceoryx2 node (as separate actor processes
//! would have), send full [`TransitionBatch`]es under the lossless `Block` policy into one
//! subscriber that copies every batch out (as the learner does into its replay). The report
//! counts what was sent and received, so loss is measured, not assumed.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Barrier;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use terl_transport::{
    Message, MessageSink, OverflowPolicy, RunTransport, Transition, TransitionBatch, Transport,
    TransportConfig, TransportError, TransportKind, ZenohConfig, ZenohMode, OBS_DIM,
    TRANSITIONS_PER_BATCH,
};

/// Result of one [`shm_throughput`] run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShmBenchReport {
    /// The transport measured: `"iceoryx2"` (shared memory), `"zenoh-tcp-loopback"`, or the
    /// label of a cross-host [`zenoh_receive`].
    pub transport: String,
    /// Publishers sending concurrently (each with its own sequence numbers).
    pub publishers: usize,
    /// Observation width of each transition ([`OBS_DIM`]).
    pub obs_dim: usize,
    /// Transitions per batch message ([`TRANSITIONS_PER_BATCH`]).
    pub transitions_per_batch: usize,
    /// Bytes of one [`Transition`] in the message.
    pub transition_bytes: usize,
    /// Seconds measured.
    pub seconds: f64,
    /// Batches the publishers sent, summed.
    pub batches_sent: u64,
    /// Batches the subscriber received.
    pub batches_received: u64,
    /// Transitions in the received batches.
    pub transitions_received: u64,
    /// Batches sent but never received (must be 0).
    pub lost_batches: u64,
    /// Batches received out of per-publisher order (must be 0).
    pub out_of_order: u64,
    /// Sends that met a full receiver and waited (back-pressure, not loss).
    pub full_events: u64,
    /// Transitions received per second.
    pub transitions_per_sec: f64,
    /// Payload bytes per second through shared memory, in 10⁹ B/s.
    pub gigabytes_per_sec: f64,
}

/// How long the end of a measurement waits for messages still in flight.
const DRAIN_QUIET: Duration = Duration::from_millis(500);

fn filled_batch(actor: u16) -> Box<TransitionBatch> {
    let mut batch = TransitionBatch::empty();
    batch.actor_id = actor;
    for i in 0..TRANSITIONS_PER_BATCH {
        let mut t = Transition::ZERO;
        for k in 0..OBS_DIM {
            t.obs[k] = (i * OBS_DIM + k) as f32 * 1e-3;
            t.next_obs[k] = t.obs[k] + 1e-4;
        }
        t.action = [0.1, -0.1, 0.2, -0.2];
        t.reward = i as f32;
        t.actor_id = actor;
        let _ = batch.push(t);
    }
    batch
}

/// Streams transitions from `publishers` publishers into one subscriber for `seconds`.
pub fn shm_throughput(publishers: usize, seconds: f64) -> Result<ShmBenchReport, TransportError> {
    throughput(TransportKind::Shm, publishers, seconds)
}

/// [`shm_throughput`] over `kind`: for Zenoh, the subscriber's session listens on a free
/// loopback TCP port and every publisher's session connects to it (peer mode), so every
/// batch crosses TCP.
pub fn throughput(
    kind: TransportKind,
    publishers: usize,
    seconds: f64,
) -> Result<ShmBenchReport, TransportError> {
    if publishers == 0 || !seconds.is_finite() || seconds <= 0.0 {
        return Err(TransportError::Config(
            "bench needs ≥ 1 publisher and a positive duration".into(),
        ));
    }
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    let config = TransportConfig {
        overflow: OverflowPolicy::Block,
        buffer_batches: 64,
        ..TransportConfig::new(format!("bench-{}-{nanos}", std::process::id()), publishers)
    };
    let (learner_config, config) = match kind {
        TransportKind::Shm => (config.clone(), config),
        TransportKind::Zenoh => {
            let port = std::net::TcpListener::bind("127.0.0.1:0")
                .and_then(|l| l.local_addr())
                .map_err(|e| TransportError::Config(format!("no free loopback port: {e}")))?
                .port();
            let endpoint = format!("tcp/127.0.0.1:{port}");
            let zenoh = |listen: Vec<String>, connect: Vec<String>| TransportConfig {
                transport: TransportKind::Zenoh,
                zenoh: ZenohConfig {
                    listen,
                    connect,
                    ..ZenohConfig::default()
                },
                ..config.clone()
            };
            (
                zenoh(vec![endpoint.clone()], vec![]),
                zenoh(vec!["tcp/127.0.0.1:0".into()], vec![endpoint]),
            )
        }
    };
    let learner = RunTransport::open(learner_config, "bench-learner")?;
    let mut source = learner.source::<TransitionBatch>()?;

    let stop = AtomicBool::new(false);
    let finished = AtomicU64::new(0);
    let ready = Barrier::new(publishers + 1);
    let duration = Duration::from_secs_f64(seconds);

    std::thread::scope(|scope| {
        let mut handles = Vec::with_capacity(publishers);
        for actor in 0..publishers {
            let (config, stop, ready, finished) = (&config, &stop, &ready, &finished);
            handles.push(
                scope.spawn(move || -> Result<PublishReport, TransportError> {
                    let result = open_publisher(config, actor);
                    ready.wait();
                    let (_transport, mut sink) = match result {
                        Ok(v) => v,
                        Err(e) => {
                            finished.fetch_add(1, Ordering::Release);
                            return Err(e);
                        }
                    };
                    let outcome = send_until(&mut *sink, actor, || stop.load(Ordering::Relaxed));
                    finished.fetch_add(1, Ordering::Release);
                    outcome
                }),
            );
        }

        ready.wait();
        let start = Instant::now();
        let mut out = TransitionBatch::empty();
        let mut tally = Tally::new(publishers);
        let elapsed = loop {
            if source.try_receive_into(&mut out)? {
                tally.count(&out);
                continue;
            }
            if !stop.load(Ordering::Relaxed) {
                if start.elapsed() >= duration {
                    stop.store(true, Ordering::Relaxed);
                }
                std::thread::yield_now();
            } else if finished.load(Ordering::Acquire) as usize == publishers {
                // Drain after the last publisher stopped, until nothing more arrives for
                // `DRAIN_QUIET` (a network transport still has messages in flight).
                let mut last = start.elapsed();
                let mut quiet = Instant::now();
                while quiet.elapsed() < DRAIN_QUIET {
                    if source.try_receive_into(&mut out)? {
                        tally.count(&out);
                        last = start.elapsed();
                        quiet = Instant::now();
                    } else {
                        std::thread::yield_now();
                    }
                }
                break last;
            }
        };

        let sent = PublishReport::total(
            handles
                .into_iter()
                .map(|h| h.join().expect("bench publisher panicked")),
        )?;
        let transport = match kind {
            TransportKind::Shm => "iceoryx2",
            TransportKind::Zenoh => "zenoh-tcp-loopback",
        };
        Ok(tally.report(transport, elapsed.as_secs_f64(), sent))
    })
}

/// What a receiver counted.
struct Tally {
    /// Next expected sequence number per publisher.
    next_seq: Vec<u64>,
    received: u64,
    transitions: u64,
    /// Batches received out of per-publisher order.
    out_of_order: u64,
}

impl Tally {
    fn new(publishers: usize) -> Self {
        Self {
            next_seq: vec![0; publishers],
            received: 0,
            transitions: 0,
            out_of_order: 0,
        }
    }

    fn count(&mut self, batch: &TransitionBatch) {
        self.received += 1;
        self.transitions += u64::from(batch.len);
        let publishers = self.next_seq.len();
        let expected = &mut self.next_seq[batch.actor_id as usize % publishers];
        if batch.sequence != *expected {
            self.out_of_order += 1;
        }
        *expected = batch.sequence + 1;
    }

    /// The report of a measurement over `secs` seconds in which the publishers sent `sent`.
    fn report(self, transport: &str, secs: f64, sent: PublishReport) -> ShmBenchReport {
        let per_sec = if secs > 0.0 {
            self.transitions as f64 / secs
        } else {
            0.0
        };
        ShmBenchReport {
            transport: transport.to_owned(),
            publishers: self.next_seq.len(),
            obs_dim: OBS_DIM,
            transitions_per_batch: TRANSITIONS_PER_BATCH,
            transition_bytes: core::mem::size_of::<Transition>(),
            seconds: secs,
            batches_sent: sent.batches_sent,
            batches_received: self.received,
            transitions_received: self.transitions,
            lost_batches: sent.batches_sent.saturating_sub(self.received),
            out_of_order: self.out_of_order,
            full_events: sent.full_events,
            transitions_per_sec: per_sec,
            gigabytes_per_sec: per_sec * core::mem::size_of::<Transition>() as f64 / 1e9,
        }
    }
}

type Publisher = (RunTransport, Box<dyn MessageSink<TransitionBatch>>);

/// A publisher's own session and sink, once the receiver is there (at most 10 s).
fn open_publisher(config: &TransportConfig, actor: usize) -> Result<Publisher, TransportError> {
    let transport = RunTransport::open(config.clone(), &format!("bench-actor-{actor}"))?;
    let sink = transport.sink::<TransitionBatch>()?;
    sink.wait_for_receivers(1, Duration::from_secs(10))?;
    Ok((transport, sink))
}

/// Sends full batches numbered 0, 1, … under `Block` until `done()`.
fn send_until(
    sink: &mut dyn MessageSink<TransitionBatch>,
    actor: usize,
    mut done: impl FnMut() -> bool,
) -> Result<PublishReport, TransportError> {
    let mut batch = filled_batch(actor as u16);
    let mut sent = 0u64;
    while !done() {
        batch.sequence = sent;
        sink.send(&batch)?;
        sent += 1;
    }
    Ok(PublishReport {
        batches_sent: sent,
        full_events: sink.stats().full_events,
    })
}

/// What the publishing half of a cross-host measurement ([`zenoh_publish`]) sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PublishReport {
    /// Batches this publisher sent.
    pub batches_sent: u64,
    /// Sends that met a full receiver and waited (back-pressure, not loss).
    pub full_events: u64,
}

impl PublishReport {
    /// The sum of the publishers' reports, or the first error.
    fn total(
        reports: impl IntoIterator<Item = Result<Self, TransportError>>,
    ) -> Result<Self, TransportError> {
        reports.into_iter().try_fold(
            Self {
                batches_sent: 0,
                full_events: 0,
            },
            |total, r| {
                let r = r?;
                Ok(Self {
                    batches_sent: total.batches_sent + r.batches_sent,
                    full_events: total.full_events + r.full_events,
                })
            },
        )
    }
}

/// The measurement's transport between two network namespaces of this machine. Its endpoints
/// are not loopback, so its sessions speak QUIC and authenticate
/// ([`ZenohConfig::check_locked`]) as a run's do; both halves derive the same secret from the
/// bench's run id (a throw-away run in private namespaces, not a credential), so QUIC and the
/// authenticated handshake are part of what is measured.
fn remote_config(run_id: &str, publishers: usize, zenoh: ZenohConfig) -> TransportConfig {
    TransportConfig {
        overflow: OverflowPolicy::Block,
        buffer_batches: 64,
        transport: TransportKind::Zenoh,
        zenoh: ZenohConfig {
            secret: terl_transport::ZenohSecret::new(format!("terl-bench-{run_id}-secret")).ok(),
            ..zenoh
        },
        ..TransportConfig::new(run_id, publishers)
    }
}

/// Publishing half of a measurement between hosts (network namespaces in `terl bench
/// transport --netns`): `publishers` threads, each with its own Zenoh client session connected
/// to `connect` (the receiver's `quic/` endpoint, its certificate checked against `ca`), send
/// full batches for `seconds` under `Block`.
///
/// # Errors
/// A session that cannot open or a receiver that does not appear within 10 s.
pub fn zenoh_publish(
    connect: &str,
    ca: &std::path::Path,
    run_id: &str,
    publishers: usize,
    seconds: f64,
) -> Result<PublishReport, TransportError> {
    let config = remote_config(
        run_id,
        publishers,
        ZenohConfig {
            mode: ZenohMode::Client,
            connect: vec![connect.to_owned()],
            tls: terl_transport::ZenohTls {
                ca: Some(ca.to_path_buf()),
                ..terl_transport::ZenohTls::default()
            },
            ..ZenohConfig::default()
        },
    );
    let duration = Duration::from_secs_f64(seconds);
    let ready = Barrier::new(publishers);
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..publishers)
            .map(|actor| {
                let (config, ready) = (&config, &ready);
                scope.spawn(move || -> Result<PublishReport, TransportError> {
                    let opened = open_publisher(config, actor);
                    ready.wait();
                    let (_transport, mut sink) = opened?;
                    let start = Instant::now();
                    send_until(&mut *sink, actor, || start.elapsed() >= duration)
                })
            })
            .collect();
        PublishReport::total(
            handles
                .into_iter()
                .map(|h| h.join().expect("bench publisher panicked")),
        )
    })
}

/// Receiving half of a measurement between hosts: a Zenoh peer listening on `listen` (a
/// `quic/` endpoint presenting `tls.cert`) takes batches from `publishers` remote publishers ([`zenoh_publish`]) until `publisher_done`
/// returns what they sent and nothing more has arrived for 500 ms. `publisher_done` is first
/// called once the session listens (start the publishers there) and then polled. The rate is
/// over the span from the first to the last batch received; loss is sent minus received.
///
/// # Errors
/// A session that cannot open, or `publisher_done` failing (the publishing process failed).
pub fn zenoh_receive(
    listen: &str,
    tls: terl_transport::ZenohTls,
    run_id: &str,
    publishers: usize,
    label: &str,
    mut publisher_done: impl FnMut() -> Result<Option<PublishReport>, TransportError>,
) -> Result<ShmBenchReport, TransportError> {
    let config = remote_config(
        run_id,
        publishers,
        ZenohConfig {
            listen: vec![listen.to_owned()],
            tls,
            ..ZenohConfig::default()
        },
    );
    let learner = RunTransport::open(config, "bench-learner")?;
    let mut source = learner.source::<TransitionBatch>()?;
    let mut out = TransitionBatch::empty();
    let mut tally = Tally::new(publishers);
    let (mut first, mut last) = (None::<Instant>, Instant::now());
    let mut done: Option<(PublishReport, Instant)> = None;
    loop {
        if source.try_receive_into(&mut out)? {
            let now = Instant::now();
            first.get_or_insert(now);
            last = now;
            tally.count(&out);
            continue;
        }
        match &done {
            None => {
                if let Some(report) = publisher_done()? {
                    done = Some((report, Instant::now()));
                }
                std::thread::sleep(Duration::from_micros(50));
            }
            Some((_, at)) if at.elapsed() > DRAIN_QUIET && last.elapsed() > DRAIN_QUIET => break,
            Some(_) => std::thread::yield_now(),
        }
    }
    let (sent, _) = done.expect("loop ends after the publishers");
    let secs = first.map_or(0.0, |f| last.duration_since(f).as_secs_f64());
    Ok(tally.report(label, secs, sent))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_run_is_lossless_and_ordered() {
        for publishers in [1, 2] {
            let r = shm_throughput(publishers, 0.2).unwrap();
            assert_eq!(r.lost_batches, 0, "{r:?}");
            assert_eq!(r.out_of_order, 0, "{r:?}");
            assert!(r.batches_received > 0);
            assert_eq!(
                r.transitions_received,
                r.batches_received * TRANSITIONS_PER_BATCH as u64
            );
            let json = serde_json::to_string(&r).unwrap();
            assert!(json.contains("\"transitions_per_sec\""));
        }
    }

    /// The two halves of a cross-host measurement, here in two threads on loopback over QUIC
    /// as between hosts: every batch the publishers sent is received, in order.
    #[test]
    fn remote_halves_count_every_batch() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let endpoint = format!("quic/127.0.0.1:{port}");
        let run = format!("bench-halves-{}", std::process::id());
        let certs = tempfile::tempdir().unwrap();
        let files = terl_wire::certs::write_run_certificates(
            certs.path(),
            "bench test",
            &["127.0.0.1".into()],
        )
        .unwrap();
        let tls = terl_transport::ZenohTls {
            ca: Some(files.ca.clone()),
            cert: Some(files.cert),
            key: Some(files.key),
        };
        // The publishers start once the receiver listens (its first call of the callback),
        // as `terl bench transport --netns` starts its publishing process.
        let mut publisher = None;
        let r = zenoh_receive(&endpoint, tls, &run, 2, "zenoh-test", || {
            let handle = publisher.get_or_insert_with(|| {
                let (endpoint, run, ca) = (endpoint.clone(), run.clone(), files.ca.clone());
                std::thread::spawn(move || zenoh_publish(&endpoint, &ca, &run, 2, 0.3))
            });
            if handle.is_finished() {
                let handle = publisher.take().unwrap();
                return handle.join().unwrap().map(Some);
            }
            Ok(None)
        })
        .unwrap();
        assert!(r.batches_sent > 0);
        assert_eq!((r.lost_batches, r.out_of_order), (0, 0), "{r:?}");
        assert_eq!(r.batches_received, r.batches_sent, "{r:?}");
    }

    #[test]
    fn zenoh_short_run_is_lossless_and_ordered() {
        let r = throughput(TransportKind::Zenoh, 2, 0.3).unwrap();
        assert_eq!(r.transport, "zenoh-tcp-loopback");
        assert_eq!((r.lost_batches, r.out_of_order), (0, 0), "{r:?}");
        assert!(r.batches_received > 0);
        assert_eq!(r.batches_received, r.batches_sent, "{r:?}");
    }

    #[test]
    fn rejects_nonsense_arguments() {
        assert!(shm_throughput(0, 1.0).is_err());
        assert!(shm_throughput(1, 0.0).is_err());
    }
}
