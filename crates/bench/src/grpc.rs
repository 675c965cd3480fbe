//! The gRPC side of `terl bench transport` and `terl bench broadcast`.
//!
//! Both benchmarks run server and clients in this process over real loopback TCP (port 0), on a
//! two-worker tokio runtime they build themselves (the machine target has two cores), and return
//! serialisable reports. Clients in one process share the runtime with the server, so the numbers
//! include the server's and all clients' CPU on the same cores, as on a one-host cluster.

use std::time::{Duration, Instant};

use futures_util::StreamExt;
use serde::Serialize;
use tokio::net::TcpListener;
use tokio::sync::mpsc;
use tonic::{Request, Response, Status, Streaming};

use terl_wire::{
    connect_learner, serve_learner, CheckpointRequest, CheckpointSaved, LearnerBackend,
    LearnerStatus, ServeOptions, Tensor, WeightHub, Weights, WeightsKind, ACTION_DIM, OBS_DIM,
};

use crate::pb;
use crate::pb::transition_bench_server::{TransitionBench, TransitionBenchServer};

/// Bytes of one transition in the fixed shared-memory layout: obs and next_obs (2 × 39 f32),
/// action (4 f32), reward (f32), task (u32), flags (u32), policy version (u64).
pub const TRANSITION_PAYLOAD_BYTES: usize = (2 * OBS_DIM + ACTION_DIM + 1) * 4 + 4 + 4 + 8;

/// Errors of the benchmark harness itself (not of the measured path).
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The tokio runtime or the loopback listener could not be set up.
    #[error("runtime: {0}")]
    Io(#[from] std::io::Error),
    /// The learner server failed.
    #[error("server: {0}")]
    Serve(#[from] terl_wire::ServeError),
    /// A client could not connect.
    #[error("client: {0}")]
    Connect(#[from] terl_wire::ConnectError),
    /// A call failed with this gRPC status.
    #[error("rpc: {0}")]
    Rpc(#[from] Status),
    /// Anything else of the harness: a server task that failed, a bad endpoint, a version not
    /// delivered within 10 s.
    #[error("{0}")]
    Harness(String),
}

fn runtime() -> std::io::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
}

// ------------------------------------------------------------------------ transition stream

/// Result of [`grpc_transition_stream`].
#[derive(Debug, Clone, Serialize)]
pub struct TransitionStreamReport {
    /// Always `"grpc"` (the shared-memory and Zenoh rows come from [`crate::transport`]).
    pub transport: &'static str,
    /// Seconds the client streamed, until the server's summary arrived.
    pub seconds: f64,
    /// Transitions per batch message.
    pub batch_transitions: usize,
    /// Batches the server received.
    pub batches: u64,
    /// Transitions in those batches.
    pub transitions: u64,
    /// Transitions received per second.
    pub transitions_per_second: f64,
    /// Bytes of the fixed layout per transition ([`TRANSITION_PAYLOAD_BYTES`]).
    pub payload_bytes_per_transition: usize,
    /// Payload throughput, 10^6 bytes/s of the fixed layout.
    pub payload_mb_per_second: f64,
    /// Protobuf bytes per batch on the wire (before HTTP/2 framing).
    pub encoded_bytes_per_batch: usize,
    /// Batches the server received but could not account for (must be 0).
    pub malformed_batches: u64,
}

#[derive(Debug, Default)]
struct CountingSink;

#[tonic::async_trait]
impl TransitionBench for CountingSink {
    async fn stream_transitions(
        &self,
        request: Request<Streaming<pb::TransitionBatch>>,
    ) -> Result<Response<pb::TransitionStreamSummary>, Status> {
        let mut stream = request.into_inner();
        let mut summary = pb::TransitionStreamSummary::default();
        while let Some(batch) = stream.next().await {
            let batch = batch?;
            let n = batch.count as usize;
            let (od, ad) = (batch.obs_dim as usize, batch.action_dim as usize);
            let consistent = batch.obs.len() == n * od
                && batch.next_obs.len() == n * od
                && batch.action.len() == n * ad
                && batch.reward.len() == n
                && batch.task.len() == n
                && batch.flags.len() == n
                && batch.policy_version.len() == n;
            summary.batches += 1;
            if consistent {
                summary.transitions += n as u64;
            } else {
                summary.malformed_batches += 1;
            }
        }
        Ok(Response::new(summary))
    }
}

/// A deterministic batch of `n` Meta-World-sized transitions.
pub fn transition_batch(n: usize, version: u64) -> pb::TransitionBatch {
    let value = |i: usize| ((i * 7919) % 1000) as f32 * 1e-3 - 0.5;
    pb::TransitionBatch {
        count: n as u32,
        obs_dim: OBS_DIM as u32,
        action_dim: ACTION_DIM as u32,
        obs: (0..n * OBS_DIM).map(value).collect(),
        next_obs: (0..n * OBS_DIM).map(|i| value(i + 1)).collect(),
        action: (0..n * ACTION_DIM).map(value).collect(),
        reward: (0..n).map(value).collect(),
        task: (0..n).map(|i| (i % 10) as u32).collect(),
        flags: vec![0; n],
        policy_version: vec![version; n],
    }
}

/// Streams batches of 64 transitions client → server over loopback gRPC for `seconds`.
pub fn grpc_transition_stream(seconds: f64) -> Result<TransitionStreamReport, BenchError> {
    runtime()?.block_on(grpc_transition_stream_async(seconds, 64))
}

/// [`grpc_transition_stream`] inside an existing runtime, with a chosen batch size.
pub async fn grpc_transition_stream_async(
    seconds: f64,
    batch_transitions: usize,
) -> Result<TransitionStreamReport, BenchError> {
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    // The production servers' transport settings (window sizes, message limit, no delay), on a
    // plain server: no token or TLS to check, no health or reflection to serve.
    let options = ServeOptions::default();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let router = tonic::transport::Server::builder()
        .initial_stream_window_size(options.stream_window_bytes)
        .initial_connection_window_size(options.connection_window_bytes)
        .add_service(
            TransitionBenchServer::new(CountingSink)
                .max_decoding_message_size(options.max_message_bytes),
        );
    let server = tokio::spawn(async move {
        let incoming =
            tonic::transport::server::TcpIncoming::from(listener).with_nodelay(Some(true));
        router
            .serve_with_incoming_shutdown(incoming, async {
                let _ = stopped.await;
            })
            .await
    });

    let channel = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
        .map_err(|e| BenchError::Harness(e.to_string()))?
        .tcp_nodelay(true)
        .initial_stream_window_size(4 << 20)
        .initial_connection_window_size(16 << 20)
        .connect()
        .await
        .map_err(|e| BenchError::Harness(format!("connect {addr}: {e}")))?;
    let mut client = pb::transition_bench_client::TransitionBenchClient::new(channel);

    let template = transition_batch(batch_transitions, 1);
    let encoded_bytes_per_batch = prost::Message::encoded_len(&template);
    let duration = Duration::from_secs_f64(seconds);
    let start = Instant::now();
    // Each batch is a fresh clone, as an actor would build a new batch per send.
    let outgoing = futures_util::stream::unfold((), move |()| {
        let batch = template.clone();
        async move { (start.elapsed() < duration).then_some((batch, ())) }
    });
    let summary = client.stream_transitions(outgoing).await?.into_inner();
    let elapsed = start.elapsed().as_secs_f64();
    let _ = stop.send(());
    server
        .await
        .map_err(|e| BenchError::Harness(e.to_string()))?
        .map_err(|e| BenchError::Harness(e.to_string()))?;

    let tps = summary.transitions as f64 / elapsed;
    Ok(TransitionStreamReport {
        transport: "grpc",
        seconds: elapsed,
        batch_transitions,
        batches: summary.batches,
        transitions: summary.transitions,
        transitions_per_second: tps,
        payload_bytes_per_transition: TRANSITION_PAYLOAD_BYTES,
        payload_mb_per_second: tps * TRANSITION_PAYLOAD_BYTES as f64 / 1e6,
        encoded_bytes_per_batch,
        malformed_batches: summary.malformed_batches,
    })
}

// ------------------------------------------------------------------------ broadcast latency

/// Layer sizes of the reference policy: (39 obs + 10 task one-hot) → 400 → 400 → 400 → 8
/// (mean and log-std of the 4-dim action).
pub const POLICY_LAYERS: [usize; 5] = [OBS_DIM + 10, 400, 400, 400, 2 * ACTION_DIM];

/// A policy-shaped weight set (weights + biases of each layer) whose values depend on `version`.
pub fn policy_weights(version: u64, layers: &[usize]) -> Weights {
    let mut tensors = Vec::new();
    for (i, pair) in layers.windows(2).enumerate() {
        let (fan_in, fan_out) = (pair[0], pair[1]);
        let seed = version as f32 * 1e-3;
        let w: Vec<f32> = (0..fan_in * fan_out)
            .map(|j| ((j % 97) as f32 - 48.0) * 1e-3 + seed)
            .collect();
        tensors.push(
            Tensor::new(format!("actor.{i}.weight"), vec![fan_out, fan_in], w).expect("shape"),
        );
        tensors.push(
            Tensor::new(
                format!("actor.{i}.bias"),
                vec![fan_out],
                vec![seed; fan_out],
            )
            .expect("shape"),
        );
    }
    Weights::new(WeightsKind::Policy, version, version * 100, tensors).expect("valid policy")
}

/// Result of [`broadcast_latency`].
#[derive(Debug, Clone, Serialize)]
pub struct BroadcastReport {
    /// Separately connected subscriber clients.
    pub subscribers: usize,
    /// Versions published.
    pub versions: u64,
    /// `f32` parameters of each version (a 3×400 policy).
    pub parameters: usize,
    /// Bytes of one encoded `WeightsUpdate` (protobuf, before HTTP/2 framing).
    pub encoded_bytes_per_version: usize,
    /// Publish (including encoding and CRC) → received, validated and decoded to `Vec<f32>` at
    /// each subscriber; one sample per (version, subscriber).
    pub samples: usize,
    /// Median latency, milliseconds.
    pub latency_ms_p50: f64,
    /// 95th-percentile latency, milliseconds.
    pub latency_ms_p95: f64,
    /// Largest latency, milliseconds.
    pub latency_ms_max: f64,
    /// Versions a subscriber never saw because a newer one overtook it (latest-wins).
    pub skipped: u64,
    /// The target for `latency_ms_p95`: 20 ms.
    pub floor_p95_ms: f64,
    /// Whether `latency_ms_p95 <= floor_p95_ms`.
    pub meets_floor: bool,
}

/// A learner backend that only publishes weights (for weight-broadcast benchmarks): status is
/// empty and checkpoints are refused.
#[derive(Debug, Clone)]
pub struct HubOnly(pub WeightHub);

impl LearnerBackend for HubOnly {
    async fn status(&self) -> Result<LearnerStatus, Status> {
        Ok(LearnerStatus::default())
    }
    async fn save_checkpoint(&self, _: CheckpointRequest) -> Result<CheckpointSaved, Status> {
        Err(Status::unimplemented(
            "benchmark learner has no checkpoints",
        ))
    }
    fn weight_hub(&self) -> &WeightHub {
        &self.0
    }
}

/// Publishes `versions` versions of a 3×400 policy to `subscribers` separately connected clients
/// and measures publish → validated receipt. Versions are published one at a time, each after
/// every subscriber received the previous one plus a 5 ms gap (a learner publishes every K
/// updates, tens of milliseconds apart), so the numbers are per-version latency, not queueing.
pub fn broadcast_latency(subscribers: usize, versions: u64) -> Result<BroadcastReport, BenchError> {
    runtime()?.block_on(broadcast_latency_async(subscribers, versions))
}

/// [`broadcast_latency`] inside an existing runtime.
pub async fn broadcast_latency_async(
    subscribers: usize,
    versions: u64,
) -> Result<BroadcastReport, BenchError> {
    let hub = WeightHub::new();
    let listener = TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?.to_string();
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let server = tokio::spawn(serve_learner(listener, HubOnly(hub.clone()), async {
        let _ = stopped.await;
    }));

    let (receipts_tx, mut receipts) = mpsc::unbounded_channel::<(usize, u64, Instant)>();
    let mut tasks = Vec::new();
    for id in 0..subscribers {
        let mut client = connect_learner(&addr).await?;
        let mut stream = client.watch_weights(&[WeightsKind::Policy]).await?;
        let tx = receipts_tx.clone();
        tasks.push(tokio::spawn(async move {
            while let Some(item) = stream.next().await {
                let weights = item?;
                // Touch the decoded values so the receive side does all an actor would.
                std::hint::black_box(weights.parameter_count());
                if tx.send((id, weights.version(), Instant::now())).is_err() {
                    break;
                }
            }
            Ok::<(), Status>(())
        }));
    }
    drop(receipts_tx);
    // Wait until every stream is registered at the hub before the first publish.
    let deadline = Instant::now() + Duration::from_secs(10);
    while hub.subscriber_count() < subscribers {
        if Instant::now() > deadline {
            return Err(BenchError::Harness("subscribers did not register".into()));
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }

    let prepared: Vec<Weights> = (1..=versions)
        .map(|v| policy_weights(v, &POLICY_LAYERS))
        .collect();
    let parameters = prepared.first().map_or(0, Weights::parameter_count);
    let encoded_bytes_per_version = prepared.first().map_or(0, |w| {
        prost::Message::encoded_len(&terl_wire::pb::WeightsUpdate::from(w))
    });
    let mut latencies_ms = Vec::with_capacity(subscribers * versions as usize);
    let mut skipped = 0u64;
    let mut last_seen = vec![0u64; subscribers];
    for weights in prepared {
        let version = weights.version();
        let published = Instant::now();
        hub.publish(&weights)
            .map_err(|e| BenchError::Harness(e.to_string()))?;
        let mut pending = subscribers;
        while pending > 0 {
            let receipt = tokio::time::timeout(Duration::from_secs(10), receipts.recv())
                .await
                .map_err(|_| {
                    BenchError::Harness(format!("version {version} not delivered within 10 s"))
                })?;
            let Some((id, got, at)) = receipt else {
                return Err(BenchError::Harness("a subscriber stream ended".into()));
            };
            skipped += got.saturating_sub(last_seen[id] + 1);
            last_seen[id] = got;
            if got == version {
                latencies_ms.push(at.duration_since(published).as_secs_f64() * 1e3);
                pending -= 1;
            }
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let _ = stop.send(());
    for task in tasks {
        task.await
            .map_err(|e| BenchError::Harness(e.to_string()))??;
    }
    server
        .await
        .map_err(|e| BenchError::Harness(e.to_string()))??;

    latencies_ms.sort_by(f64::total_cmp);
    let floor_p95_ms = 20.0;
    let p95 = percentile(&latencies_ms, 0.95);
    Ok(BroadcastReport {
        subscribers,
        versions,
        parameters,
        encoded_bytes_per_version,
        samples: latencies_ms.len(),
        latency_ms_p50: percentile(&latencies_ms, 0.50),
        latency_ms_p95: p95,
        latency_ms_max: latencies_ms.last().copied().unwrap_or(0.0),
        skipped,
        floor_p95_ms,
        meets_floor: p95 <= floor_p95_ms,
    })
}

/// Bytes of `weights` as one `WeightsUpdate` message on the wire.
pub fn encoded_len(weights: &Weights) -> usize {
    prost::Message::encoded_len(&terl_wire::pb::WeightsUpdate::from(weights))
}

/// Nearest-rank percentile of sorted values (0 for none).
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = (q * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payload_and_policy_sizes() {
        assert_eq!(TRANSITION_PAYLOAD_BYTES, 348);
        let w = policy_weights(1, &POLICY_LAYERS);
        // 49·400+400 + 2·(400·400+400) + 400·8+8
        assert_eq!(w.parameter_count(), 344_008);
    }

    #[test]
    fn nearest_rank_percentile() {
        let v: Vec<f64> = (1..=20).map(f64::from).collect();
        assert_eq!(percentile(&v, 0.5), 10.0);
        assert_eq!(percentile(&v, 0.95), 19.0);
        assert_eq!(percentile(&[], 0.95), 0.0);
    }
}
