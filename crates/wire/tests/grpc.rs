//! terl-wire over real gRPC on 127.0.0.1, port 0: status, weight streaming, edge validation,
//! size limits, health, shutdown, and a Python grpcio client we did not write.

use std::future::Future;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::pin::Pin;
use std::time::Duration;

use futures_util::{Stream, StreamExt};
use terl_wire::pb;
use terl_wire::{
    connect_learner, connect_learner_with, connect_selector, serve_learner, serve_learner_with,
    serve_selector, weights_crc32, ActorStats, CheckpointRequest, CheckpointSaved, ClientOptions,
    LearnerBackend, LearnerStatus, PriorityStats, SelectorBackend, SelectorStatus, ServeOptions,
    TaskSuccess, Tensor, Watcher, WeightHub, Weights, WeightsKind,
};
use tokio::net::TcpListener;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tonic::{Code, Request, Response, Status};

const WAIT: Duration = Duration::from_secs(10);

fn learner_status() -> LearnerStatus {
    LearnerStatus {
        run_id: "test-run".into(),
        uptime_seconds: 12.5,
        updates: 1234,
        updates_per_second: 98.5,
        env_steps_total: 50_000,
        actors: vec![ActorStats {
            actor_id: 1,
            env_steps: 25_000,
            env_steps_per_second: 1900.0,
            policy_version: 7,
            seconds_since_seen: 0.1,
            transition_batches_dropped: 3,
            transitions_dropped: 192,
            episodes_dropped: 2,
            host: String::new(),
            address: String::new(),
        }],
        replay_size: 50_000,
        replay_capacity: 1_000_000,
        task_success: vec![TaskSuccess {
            task: "door-open".into(),
            success_rate: 0.42,
            episodes: 50,
            guidance_rate: 0.125,
            guidance_probability: Some(0.81),
            not_improving_rate: Some(0.375),
            action_gap: Some(1.5),
            compared_steps: 64,
        }],
        staleness_mean: 3.5,
        staleness_max: 9,
        rejected_batches: 2,
        policy_version: 7,
        planner_version: 3,
        tep_updates: 40,
        algorithm: "terl".into(),
        tep_buffer_size: 2048,
        tep_buffer_capacity: 6_000_000,
        tep_f_loss: 1.75,
        tep_an_loss: 12.5,
        selected_samples: 2048,
        tep_after_success: 17,
        guided_steps: 99,
        tep_target_mean: 14.5,
        tep_goal_distance_mean: 13.25,
        planner: terl_wire::PlannerStatus {
            step_loss: 0.25,
            goal_loss: 1.5,
            symmetry_loss: 0.125,
            an_bc_loss: 0.375,
            gap_mean: 16.5,
            tasks: vec![
                terl_wire::PlannerTask {
                    task: "reach".into(),
                    spearman: Some(0.875),
                    validated: true,
                    validated_at_tep_update: 400,
                    tep_transitions: 1024,
                    held_out_trajectories: 4,
                    held_out_transitions: 48,
                },
                terl_wire::PlannerTask {
                    task: "push".into(),
                    spearman: None,
                    ..Default::default()
                },
            ],
        },
        transition_batches_dropped: 3,
        transitions_dropped: 192,
        episodes_dropped: 2,
        selected_batches_dropped: 1,
        selected_samples_dropped: 512,
        resumed_from: "runs/test/checkpoints/update-0000000100.safetensors".into(),
        resumed_at_update: 100,
        checkpoint_failures: 1,
        transition_batches_missed: 6,
        standalone_updates_per_second: 120.5,
        busy_updates_per_second: 110.25,
        update_speed_ratio: 110.25 / 120.5,
        staging_max_ms: 0.75,
    }
}

struct TestLearner {
    hub: WeightHub,
}

impl LearnerBackend for TestLearner {
    async fn status(&self) -> Result<LearnerStatus, Status> {
        Ok(learner_status())
    }
    async fn save_checkpoint(&self, request: CheckpointRequest) -> Result<CheckpointSaved, Status> {
        Ok(CheckpointSaved {
            path: format!(
                "runs/test/checkpoints/{}.safetensors",
                request.label.unwrap_or_default()
            ),
            learner_update: 1234,
            policy_version: self.hub.latest_version(WeightsKind::Policy),
        })
    }
    fn weight_hub(&self) -> &WeightHub {
        &self.hub
    }
    /// The status lists actors 0 and 1 of a two-actor run.
    fn actor_slots(&self) -> Option<u32> {
        Some(2)
    }
}

struct TestSelector;

impl SelectorBackend for TestSelector {
    async fn status(&self) -> Result<SelectorStatus, Status> {
        Ok(SelectorStatus {
            run_id: "test-run".into(),
            uptime_seconds: 3.0,
            episodes_seen: 40,
            task_success: vec![TaskSuccess {
                task: "reach".into(),
                success_rate: 0.9,
                episodes: 20,
                ..Default::default()
            }],
            selected_samples: 512,
            priority: PriorityStats {
                scored: 1024,
                mean: 0.2,
                min: -0.5,
                max: 1.5,
                selection_threshold: 0.7,
                gae_part_mean: 0.05,
                entropy_part_mean: 0.15,
            },
            critic_version: 3,
            episodes_dropped: 2,
            episodes_missed: 1,
            ..Default::default()
        })
    }
}

/// A running server: address, a way to stop it, and its task.
struct Running {
    addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    task: JoinHandle<Result<(), terl_wire::ServeError>>,
}

impl Running {
    async fn stop(mut self) {
        let _ = self.stop.take().expect("stopped once").send(());
        tokio::time::timeout(WAIT, self.task)
            .await
            .expect("server stops within 10 s")
            .expect("server task")
            .expect("server result");
    }
}

type ServeFn<B> = fn(
    TcpListener,
    B,
    Pin<Box<dyn Future<Output = ()> + Send>>,
) -> Pin<Box<dyn Future<Output = Result<(), terl_wire::ServeError>> + Send>>;

async fn start<B: Send + 'static>(backend: B, serve: ServeFn<B>) -> Running {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (stop, stopped) = oneshot::channel::<()>();
    let shutdown = Box::pin(async {
        let _ = stopped.await;
    });
    let task = tokio::spawn(serve(listener, backend, shutdown));
    Running {
        addr,
        stop: Some(stop),
        task,
    }
}

async fn start_learner(hub: WeightHub) -> Running {
    start(TestLearner { hub }, |l, b, s| {
        Box::pin(serve_learner(l, b, s))
    })
    .await
}

async fn start_selector() -> Running {
    start(TestSelector, |l, b, s| Box::pin(serve_selector(l, b, s))).await
}

/// A 3×400 policy (39 obs + 10 task one-hot → 400 → 400 → 400 → 8): 344 008 parameters,
/// about 1.4 MB on the wire.
fn policy_3x400(version: u64) -> Weights {
    let layers = [49, 400, 400, 400, 8];
    let tensors = layers
        .windows(2)
        .enumerate()
        .flat_map(|(i, pair)| {
            let (fan_in, fan_out) = (pair[0], pair[1]);
            [
                Tensor::new(
                    format!("actor.{i}.weight"),
                    vec![fan_out, fan_in],
                    vec![version as f32 * 1e-3; fan_in * fan_out],
                )
                .unwrap(),
                Tensor::new(format!("actor.{i}.bias"), vec![fan_out], vec![0.5; fan_out]).unwrap(),
            ]
        })
        .collect();
    Weights::new(WeightsKind::Policy, version, version * 100, tensors).unwrap()
}

fn weights(kind: WeightsKind, version: u64) -> Weights {
    let tensors = vec![
        Tensor::new("l0.weight", vec![3, 2], vec![version as f32; 6]).unwrap(),
        Tensor::new("l0.bias", vec![3], vec![-(version as f32); 3]).unwrap(),
    ];
    Weights::new(kind, version, version * 10, tensors).unwrap()
}

async fn next<S: Stream<Item = Result<Weights, Status>> + Unpin>(stream: &mut S) -> Weights {
    tokio::time::timeout(WAIT, stream.next())
        .await
        .expect("a weights message within 10 s")
        .expect("stream still open")
        .expect("valid weights")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_round_trips_for_learner_and_selector() {
    let learner = start_learner(WeightHub::new()).await;
    let selector = start_selector().await;
    let mut client = connect_learner(&learner.addr.to_string()).await.unwrap();
    assert_eq!(client.status().await.unwrap(), learner_status());
    let saved = client
        .save_checkpoint(CheckpointRequest {
            label: Some("manual-1".into()),
        })
        .await
        .unwrap();
    assert_eq!(saved.path, "runs/test/checkpoints/manual-1.safetensors");
    let mut selector_client = connect_selector(&selector.addr.to_string()).await.unwrap();
    let status = selector_client.status().await.unwrap();
    assert_eq!(status, TestSelector.status().await.unwrap());
    learner.stop().await;
    selector.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn weight_stream_delivers_in_order_and_latest_to_late_subscriber() {
    let hub = WeightHub::new();
    let server = start_learner(hub.clone()).await;
    let addr = server.addr.to_string();

    let mut early = connect_learner(&addr).await.unwrap();
    let mut early = early.watch_weights(&[WeightsKind::Policy]).await.unwrap();
    let mut all_kinds = connect_learner(&addr).await.unwrap();
    let mut all_kinds = all_kinds.watch_weights(&[]).await.unwrap();
    while hub.subscriber_count() < 2 {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    for version in 1..=3 {
        hub.publish(&weights(WeightsKind::Policy, version)).unwrap();
        let got = next(&mut early).await;
        assert_eq!(got, weights(WeightsKind::Policy, version));
    }
    hub.publish(&weights(WeightsKind::Planner, 1)).unwrap();

    // The all-kinds subscriber did not read while versions 1..3 were published: it sees the
    // newest policy (maybe after older ones, always increasing) and the planner.
    let mut last_policy = 0;
    let mut planner_seen = false;
    while last_policy < 3 || !planner_seen {
        let w = next(&mut all_kinds).await;
        match w.kind() {
            WeightsKind::Policy => {
                assert!(w.version() > last_policy, "policy versions increase");
                last_policy = w.version();
            }
            WeightsKind::Planner => planner_seen = true,
            WeightsKind::Critic => panic!("no critic published"),
        }
    }

    // A late subscriber gets exactly the latest policy first, then new versions.
    let mut late = connect_learner(&addr).await.unwrap();
    let mut late = late.watch_weights(&[WeightsKind::Policy]).await.unwrap();
    assert_eq!(next(&mut late).await.version(), 3);
    hub.publish(&weights(WeightsKind::Policy, 4)).unwrap();
    assert_eq!(next(&mut late).await.version(), 4);
    assert_eq!(next(&mut early).await.version(), 4);

    // Shutdown ends the open streams instead of hanging the server.
    server.stop().await;
    let end = tokio::time::timeout(WAIT, late.next())
        .await
        .expect("stream ends");
    assert!(end.is_none() || end.unwrap().is_err());
}

/// An actor that names itself when it subscribes to the weights is listed with its host name and
/// the address its stream comes from, until its stream ends; a host name over the limit and an
/// id that is not one of the run's actors are refused at the edge (the table of named watchers
/// is bounded by the run's actor count and shrinks when actors leave).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn status_lists_the_host_and_address_of_a_watching_actor() {
    let server = start_learner(WeightHub::new()).await;
    let addr = server.addr.to_string();
    let options = ClientOptions {
        watcher: Some(Watcher {
            actor_id: 1,
            host: "node-7".into(),
        }),
        ..ClientOptions::default()
    };
    let mut client = connect_learner(&addr).await.unwrap();
    // Before the actor subscribes, its host is unknown.
    assert_eq!(client.status().await.unwrap().actors[0].host, "");
    let mut actor = connect_learner_with(&addr, options).await.unwrap();
    let _stream = actor.watch_weights(&[WeightsKind::Policy]).await.unwrap();
    let status = client.status().await.unwrap();
    let listed = &status.actors[0];
    assert_eq!(listed.host, "node-7");
    let (ip, port) = listed.address.rsplit_once(':').expect("ip:port");
    assert_eq!(ip, "127.0.0.1");
    assert!(port.parse::<u16>().unwrap() > 0);
    assert_ne!(
        port,
        server.addr.port().to_string(),
        "the client's port, not the server's"
    );

    let mut raw = pb::learner_client::LearnerClient::connect(format!("http://{addr}"))
        .await
        .unwrap();
    let Err(err) = raw
        .watch_weights(pb::WatchWeightsRequest {
            kinds: vec![],
            actor_id: Some(2),
            host: "h".repeat(256),
        })
        .await
    else {
        panic!("an oversized host name is accepted");
    };
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(err.message().contains("host"), "{err}");
    let Err(err) = raw
        .watch_weights(pb::WatchWeightsRequest {
            kinds: vec![],
            actor_id: Some(2),
            host: "node-8".into(),
        })
        .await
    else {
        panic!("actor id 2 of a two-actor run is accepted");
    };
    assert_eq!(err.code(), Code::InvalidArgument);
    assert!(
        err.message().contains("not one of this run's 2 actors"),
        "{err}"
    );
    // The actor leaves: its stream and connection close, and its entry goes with them.
    drop(_stream);
    drop(actor);
    let start = std::time::Instant::now();
    while !client.status().await.unwrap().actors[0].host.is_empty() {
        assert!(start.elapsed() < WAIT, "the departed actor is still listed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    server.stop().await;
}

/// A learner that sends whatever messages a test gives it, valid or not.
struct RawLearner {
    updates: Vec<pb::WeightsUpdate>,
}

#[tonic::async_trait]
impl pb::learner_server::Learner for RawLearner {
    async fn get_status(
        &self,
        _: Request<pb::GetLearnerStatusRequest>,
    ) -> Result<Response<pb::LearnerStatus>, Status> {
        Ok(Response::new(pb::LearnerStatus {
            updates_per_second: f64::NAN,
            ..Default::default()
        }))
    }
    type WatchWeightsStream = Pin<Box<dyn Stream<Item = Result<pb::WeightsUpdate, Status>> + Send>>;
    async fn watch_weights(
        &self,
        _: Request<pb::WatchWeightsRequest>,
    ) -> Result<Response<Self::WatchWeightsStream>, Status> {
        let items: Vec<_> = self.updates.iter().cloned().map(Ok).collect();
        Ok(Response::new(Box::pin(futures_util::stream::iter(items))))
    }
    async fn save_checkpoint(
        &self,
        _: Request<pb::SaveCheckpointRequest>,
    ) -> Result<Response<pb::SaveCheckpointResponse>, Status> {
        Err(Status::unimplemented("raw"))
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_messages_are_rejected_at_the_edge_with_invalid_argument() {
    let good = pb::WeightsUpdate::from(&weights(WeightsKind::Policy, 1));
    let mut bad_crc = good.clone();
    bad_crc.crc32 ^= 0xdead_beef;
    let mut bad_shape = good.clone();
    bad_shape.tensors[0].shape = vec![2, 2];
    let mut nan = good.clone();
    let mut data = nan.tensors[1].data.to_vec();
    data[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
    nan.tensors[1].data = data.into();
    nan.crc32 = weights_crc32(&nan.tensors);
    let mut unknown_kind = good.clone();
    unknown_kind.kind = 42;

    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let updates = vec![bad_crc, bad_shape, nan, unknown_kind, good];
    let (stop, stopped) = oneshot::channel::<()>();
    let server = tokio::spawn(
        tonic::transport::Server::builder()
            .add_service(pb::learner_server::LearnerServer::new(RawLearner {
                updates,
            }))
            .serve_with_incoming_shutdown(
                tonic::transport::server::TcpIncoming::from(listener),
                async {
                    let _ = stopped.await;
                },
            ),
    );
    let mut client = connect_learner(&addr).await.unwrap();
    let mut stream = client.watch_weights(&[]).await.unwrap();
    let expect_invalid = |item: Option<Result<Weights, Status>>, needle: &str| {
        let status = item.expect("item").expect_err("rejected");
        assert_eq!(status.code(), Code::InvalidArgument, "{status:?}");
        assert!(
            status.message().contains(needle),
            "{needle:?} not in {:?}",
            status.message()
        );
    };
    expect_invalid(stream.next().await, "CRC-32 mismatch");
    expect_invalid(
        stream.next().await,
        "shape [2, 2] needs 16 bytes of little-endian f32, got 24",
    );
    expect_invalid(
        stream.next().await,
        "tensor 'l0.bias' (#1): value 1 is not finite (NaN)",
    );
    expect_invalid(stream.next().await, "unknown weights kind 42");
    // The stream survives bad items: the valid version after them arrives intact.
    assert_eq!(stream.next().await.unwrap().unwrap().version(), 1);
    // Status with a NaN rate is refused too.
    let status = client.status().await.unwrap_err();
    assert_eq!(status.code(), Code::InvalidArgument);
    assert_eq!(status.message(), "updates_per_second is not finite (NaN)");
    let _ = stop.send(());
    server.await.unwrap().unwrap();

    // Requests are validated on the server's side of the edge as well.
    let server = start_learner(WeightHub::new()).await;
    let mut client = connect_learner(&server.addr.to_string()).await.unwrap();
    let status = client
        .raw()
        .watch_weights(pb::WatchWeightsRequest {
            kinds: vec![1, 7],
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::InvalidArgument);
    assert!(
        status.message().contains("unknown weights kind 7"),
        "{status:?}"
    );
    let status = client
        .save_checkpoint(CheckpointRequest {
            label: Some("../../etc/passwd".into()),
        })
        .await
        .unwrap_err();
    assert_eq!(status.code(), Code::InvalidArgument);
    assert!(status.message().contains("[A-Za-z0-9_-]"), "{status:?}");
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_messages_fail_with_resource_exhausted_not_a_crash() {
    // Server → client: a 1.4 MB policy to a client that accepts 1 MiB.
    let hub = WeightHub::new();
    let server = start_learner(hub.clone()).await;
    let addr = server.addr.to_string();
    let small = ClientOptions {
        max_message_bytes: 1 << 20,
        ..ClientOptions::default()
    };
    let mut client = connect_learner_with(&addr, small).await.unwrap();
    let mut stream = client.watch_weights(&[WeightsKind::Policy]).await.unwrap();
    hub.publish(&policy_3x400(1)).unwrap();
    let status = tokio::time::timeout(WAIT, stream.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap_err();
    // tonic reports "decoded message length too large" as OUT_OF_RANGE.
    assert!(
        matches!(status.code(), Code::OutOfRange | Code::ResourceExhausted),
        "{status:?}"
    );
    assert!(status.message().contains("too large"), "{status:?}");
    // The server is unharmed: a default client still gets the version.
    let mut ok = connect_learner(&addr).await.unwrap();
    let mut stream = ok.watch_weights(&[WeightsKind::Policy]).await.unwrap();
    assert_eq!(next(&mut stream).await.parameter_count(), 344_008);
    server.stop().await;

    // Client → server: a request over the server's limit.
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let options = ServeOptions {
        max_message_bytes: 64 << 10,
        ..ServeOptions::default()
    };
    let (stop, stopped) = oneshot::channel::<()>();
    let backend = TestLearner {
        hub: WeightHub::with_max_message_bytes(64 << 10),
    };
    let task = tokio::spawn(serve_learner_with(
        listener,
        backend,
        async {
            let _ = stopped.await;
        },
        options,
    ));
    let mut client = connect_learner(&addr).await.unwrap();
    let status = client
        .raw()
        .save_checkpoint(pb::SaveCheckpointRequest {
            label: "x".repeat(100 << 10),
        })
        .await
        .unwrap_err();
    assert!(
        matches!(status.code(), Code::OutOfRange | Code::ResourceExhausted),
        "{status:?}"
    );
    assert!(status.message().contains("too large"), "{status:?}");
    assert_eq!(client.status().await.unwrap().updates, 1234);
    let _ = stop.send(());
    task.await.unwrap().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_reports_serving_then_not_serving() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    // A short grace: the open health Watch stream below would otherwise hold the shutdown.
    let server = start(
        TestLearner {
            hub: WeightHub::new(),
        },
        |l, b, s| {
            let options = ServeOptions {
                shutdown_grace: Duration::from_millis(300),
                ..ServeOptions::default()
            };
            Box::pin(serve_learner_with(l, b, s, options))
        },
    )
    .await;
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = HealthClient::new(channel);
    for service in ["", "terl.v1.Learner"] {
        let reply = health
            .check(HealthCheckRequest {
                service: service.into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(
            reply.status(),
            ServingStatus::Serving,
            "service {service:?}"
        );
    }
    let mut watch = health
        .watch(HealthCheckRequest {
            service: "terl.v1.Learner".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        watch.message().await.unwrap().unwrap().status(),
        ServingStatus::Serving
    );
    let stopping = tokio::spawn(server.stop());
    let next = tokio::time::timeout(WAIT, watch.message()).await.unwrap();
    if let Ok(Some(reply)) = next {
        assert_eq!(reply.status(), ServingStatus::NotServing);
    }
    stopping.await.unwrap();
}

/// `check_health` (the launcher's readiness check) finds each server's own service serving
/// and fails for the other one's name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn check_health_finds_each_server_serving_its_own_service() {
    let options = terl_wire::ClientOptions::default();
    let learner = start_learner(WeightHub::new()).await;
    let selector = start_selector().await;
    for (server, own, other) in [
        (
            &learner,
            terl_wire::LEARNER_SERVICE,
            terl_wire::SELECTOR_SERVICE,
        ),
        (
            &selector,
            terl_wire::SELECTOR_SERVICE,
            terl_wire::LEARNER_SERVICE,
        ),
    ] {
        let addr = server.addr.to_string();
        for service in ["", own] {
            let serving = terl_wire::check_health(&addr, service, &options).await;
            assert!(serving.unwrap(), "{own} at {addr}: {service:?}");
        }
        let err = terl_wire::check_health(&addr, other, &options)
            .await
            .unwrap_err();
        assert!(
            matches!(&err, terl_wire::HealthError::Rpc { status, .. } if status.code() == tonic::Code::NotFound),
            "{err}"
        );
    }
    let learner_addr = learner.addr.to_string();
    learner.stop().await;
    selector.stop().await;
    // Nothing listens any more: a connection error, not a hang.
    let gone = terl_wire::check_health(&learner_addr, "", &options).await;
    assert!(matches!(gone, Err(terl_wire::HealthError::Connect(_))));
}

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn venv_python() -> PathBuf {
    let venv = std::env::var_os("TERL_GRPC_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".deps/grpc-venv"));
    let python = venv.join("bin/python");
    assert!(
        python.exists(),
        "the Python gRPC client venv is missing ({}); create it with \
         crates/wire/tests/python/setup-venv.sh (deploy/setup.sh runs it)",
        python.display()
    );
    python
}

async fn python_client(addr: SocketAddr, service: &str, response_type: &str) -> serde_json::Value {
    let script =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/python/reflection_client.py");
    let output = tokio::time::timeout(
        Duration::from_secs(60),
        tokio::process::Command::new(venv_python())
            .arg(&script)
            .arg(addr.to_string())
            .arg(service)
            .arg("GetStatus")
            .arg(response_type)
            .kill_on_drop(true)
            .output(),
    )
    .await
    .expect("python client finishes within 60 s")
    .expect("python runs");
    assert!(
        output.status.success(),
        "python client failed: {}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).expect("python prints JSON")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_grpcio_reflection_and_health_clients_work() {
    let learner = start_learner(WeightHub::new()).await;
    let selector = start_selector().await;
    for (server, service, response, methods) in [
        (
            &learner,
            "terl.v1.Learner",
            "terl.v1.LearnerStatus",
            vec!["GetStatus", "SaveCheckpoint", "WatchWeights"],
        ),
        (
            &selector,
            "terl.v1.Selector",
            "terl.v1.SelectorStatus",
            vec!["GetStatus"],
        ),
    ] {
        let report = python_client(server.addr, service, response).await;
        for key in ["v1alpha_services", "v1_services", "v1alpha_listed"] {
            let listed: Vec<&str> = report[key]
                .as_array()
                .unwrap_or_else(|| panic!("{key} in {report}"))
                .iter()
                .map(|v| v.as_str().unwrap())
                .collect();
            for expected in [
                service,
                "grpc.health.v1.Health",
                "grpc.reflection.v1.ServerReflection",
                "grpc.reflection.v1alpha.ServerReflection",
            ] {
                assert!(
                    listed.contains(&expected),
                    "{expected} missing from {key}: {listed:?}"
                );
            }
        }
        assert_eq!(report["methods"], serde_json::json!(methods), "{report}");
        assert_eq!(report["status_run_id"], "test-run", "{report}");
        assert_eq!(report["health"][""], "SERVING", "{report}");
        assert_eq!(report["health"][service], "SERVING", "{report}");
    }
    learner.stop().await;
    selector.stop().await;
}

/// Reflection of one server: the services it lists, and for each symbol whether
/// `FileContainingSymbol` finds it.
async fn reflect(addr: SocketAddr, symbols: &[&str]) -> (Vec<String>, Vec<bool>) {
    use tonic_reflection::pb::v1::{
        server_reflection_client::ServerReflectionClient,
        server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
        ServerReflectionRequest,
    };
    let client = ServerReflectionClient::new(
        tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
            .unwrap()
            .connect()
            .await
            .unwrap(),
    );
    let request = |message: MessageRequest| ServerReflectionRequest {
        host: String::new(),
        message_request: Some(message),
    };
    // One stream per question: tonic's reflection ends a stream with a NOT_FOUND status (not
    // an error reply) when a symbol is missing.
    let ask = |message: MessageRequest| {
        let mut client = client.clone();
        async move {
            let replies = client
                .server_reflection_info(futures_util::stream::iter([request(message)]))
                .await?;
            let mut replies = replies.into_inner();
            match tokio::time::timeout(WAIT, replies.next()).await.unwrap() {
                Some(reply) => Ok(reply?.message_response.unwrap()),
                None => Err(tonic::Status::unknown(
                    "reflection stream ended without a reply",
                )),
            }
        }
    };
    let mut listed = Vec::new();
    match ask(MessageRequest::ListServices(String::new()))
        .await
        .unwrap()
    {
        MessageResponse::ListServicesResponse(list) => {
            listed.extend(list.service.into_iter().map(|s| s.name));
        }
        other => panic!("unexpected reflection reply {other:?}"),
    }
    let mut found = Vec::new();
    for symbol in symbols {
        found.push(
            match ask(MessageRequest::FileContainingSymbol(symbol.to_string())).await {
                Ok(MessageResponse::FileDescriptorResponse(files)) => {
                    !files.file_descriptor_proto.is_empty()
                }
                Ok(MessageResponse::ErrorResponse(_)) => false,
                Err(status) if status.code() == tonic::Code::NotFound => false,
                other => panic!("unexpected reflection reply for {symbol}: {other:?}"),
            },
        );
    }
    listed.sort();
    (listed, found)
}

/// The benchmarks' gRPC service and messages live in their own package (`terl.bench.v1`, crate
/// terl-bench), not in the production contract: reflection of the learner and the selector
/// neither lists nor resolves them, and the descriptor set they serve does not hold them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reflection_of_production_servers_has_no_bench_service() {
    for name in ["bench.proto", "TransitionBench", "TransitionStreamSummary"] {
        let bytes = name.as_bytes();
        assert!(
            !terl_wire::FILE_DESCRIPTOR_SET
                .windows(bytes.len())
                .any(|w| w == bytes),
            "{name} is in the production descriptor set"
        );
    }
    let learner = start_learner(WeightHub::new()).await;
    let selector = start_selector().await;
    for (server, service) in [
        (&learner, "terl.v1.Learner"),
        (&selector, "terl.v1.Selector"),
    ] {
        let symbols = [
            service,
            "terl.v1.TransitionBench",
            "terl.bench.v1.TransitionBench",
            "terl.v1.TransitionStreamSummary",
        ];
        let (listed, found) = reflect(server.addr, &symbols).await;
        let mut expected = vec![
            service,
            "grpc.health.v1.Health",
            "grpc.reflection.v1.ServerReflection",
            "grpc.reflection.v1alpha.ServerReflection",
        ];
        expected.sort();
        assert_eq!(listed, expected, "{service}");
        // The served service resolves (the check can tell found from missing); no bench symbol does.
        assert_eq!(
            found,
            vec![true, false, false, false],
            "{service}: {symbols:?}"
        );
    }
    learner.stop().await;
    selector.stop().await;
}
