//! Serving the `Learner` and `Selector` services, each with `grpc.health.v1` and server
//! reflection (`grpc.reflection.v1` and `v1alpha`, since generic clients differ in which one they
//! speak), so grpcurl or any grpcio client works without our proto files.
//!
//! Like mini-redis, the server takes a bound listener and a shutdown future: binaries bind
//! `127.0.0.1:50051`/`50052` by default, tests bind port 0. When the shutdown future completes,
//! health turns NOT_SERVING, open `WatchWeights` streams end cleanly, and in-flight unary calls
//! finish before the function returns.

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures_util::Stream;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tonic::server::NamedService;
use tonic::transport::server::{Router, TcpIncoming};
use tonic::transport::Server;
use tonic::{Request, Response, Status};
use tonic_health::ServingStatus;

use crate::hub::{Latest, WeightHub};
use crate::pb;
use crate::pb::learner_server::{Learner, LearnerServer};
use crate::pb::selector_server::{Selector, SelectorServer};
use crate::security::{AuthLayer, SecurityError, ServerSecurity};
use crate::status::{LearnerStatus, SelectorStatus};
use crate::weights::WeightsKind;
use crate::{DEFAULT_MAX_MESSAGE_BYTES, FILE_DESCRIPTOR_SET};

/// Why a server could not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// Binding or accepting on the TCP listener failed.
    #[error("listener: {0}")]
    Io(#[from] std::io::Error),
    /// tonic's HTTP/2 server failed, or rejected the TLS configuration.
    #[error("gRPC transport: {0}")]
    Transport(#[from] tonic::transport::Error),
    /// The reflection service could not be built from [`FILE_DESCRIPTOR_SET`].
    #[error("reflection service: {0}")]
    Reflection(#[from] tonic_reflection::server::Error),
    /// The security settings refuse this listener (no token on a non-loopback address) or
    /// could not be loaded.
    #[error(transparent)]
    Security(#[from] SecurityError),
}

/// Server settings that differ from tonic's defaults on purpose.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Largest message decoded or encoded, bytes. tonic's default is 4 MiB, which the TEP planner
    /// weights (F and AN, ≈ 1.1 M f32 ≈ 4.5 MB) already exceed; the default
    /// [`DEFAULT_MAX_MESSAGE_BYTES`] = 64 MiB leaves room for 3×1024 networks and targets while
    /// still refusing runaway messages with `RESOURCE_EXHAUSTED`.
    pub max_message_bytes: usize,
    /// HTTP/2 flow-control windows (stream, connection). Large enough that one policy version
    /// (≈ 1.4 MB) goes out without waiting for window updates.
    pub stream_window_bytes: u32,
    /// Connection-level HTTP/2 flow-control window, bytes (shared by all streams of a
    /// connection; default 16 MiB against the stream window's 4 MiB).
    pub connection_window_bytes: u32,
    /// After the shutdown future completes, how long to wait for open calls to finish before
    /// returning anyway. `WatchWeights` streams end at once; this bounds streams we do not
    /// control, such as a client's `grpc.health.v1.Health/Watch`, which would otherwise keep a
    /// graceful shutdown waiting forever.
    pub shutdown_grace: Duration,
    /// Token and TLS. Without a token the server refuses a non-loopback listener
    /// ([`ServeError::Security`]); with one, every RPC must carry it (see [`ServerSecurity`]).
    pub security: ServerSecurity,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            max_message_bytes: DEFAULT_MAX_MESSAGE_BYTES,
            stream_window_bytes: 4 << 20,
            connection_window_bytes: 16 << 20,
            shutdown_grace: Duration::from_secs(3),
            security: ServerSecurity::default(),
        }
    }
}

/// Binds a TCP listener; pass [`crate::DEFAULT_LEARNER_ADDR`], [`crate::DEFAULT_SELECTOR_ADDR`]
/// or `127.0.0.1:0` (tests). Loopback by default: the control plane is not meant to be exposed.
/// A non-loopback address also needs a token, which [`bind_secured`] checks before binding.
pub async fn bind(addr: SocketAddr) -> std::io::Result<TcpListener> {
    TcpListener::bind(addr).await
}

/// [`bind`] after [`ServerSecurity::check_bind`]: a non-loopback `addr` without a token is
/// refused (nothing is bound) with an error naming the token settings.
pub async fn bind_secured(
    addr: SocketAddr,
    security: &ServerSecurity,
) -> Result<TcpListener, ServeError> {
    security.check_bind(addr)?;
    Ok(TcpListener::bind(addr).await?)
}

/// What the learner process provides to its gRPC service.
pub trait LearnerBackend: Send + Sync + 'static {
    /// A fresh status snapshot.
    fn status(&self) -> impl Future<Output = Result<LearnerStatus, Status>> + Send;
    /// Writes a checkpoint now.
    fn save_checkpoint(
        &self,
        request: CheckpointRequest,
    ) -> impl Future<Output = Result<CheckpointSaved, Status>> + Send;
    /// The hub the learner publishes weights to; `WatchWeights` streams subscribe to it.
    fn weight_hub(&self) -> &WeightHub;
    /// The run's actor count: a `WatchWeights` call naming an actor id at or above it is
    /// refused, so the table of named watchers holds at most this many entries. `None`
    /// (default): ids are not checked, and the table holds at most [`MAX_WATCHERS`].
    fn actor_slots(&self) -> Option<u32> {
        None
    }
}

/// The most named weight watchers a learner keeps at once when its backend does not give its
/// actor count ([`LearnerBackend::actor_slots`]).
pub const MAX_WATCHERS: usize = 4096;

/// A named watcher: where the actor of an id follows the weights from.
#[derive(Debug)]
struct WatcherEntry {
    host: String,
    address: String,
    /// Which `WatchWeights` stream named it: only that stream's end removes it.
    stream: u64,
}

/// Actor id → the open `WatchWeights` stream that named it last.
#[derive(Debug, Default)]
struct Watchers {
    by_actor: Mutex<HashMap<u32, WatcherEntry>>,
    next_stream: std::sync::atomic::AtomicU64,
}

/// Removes its entry from the watcher table when its stream ends (the actor disconnected).
struct WatcherGuard {
    watchers: Arc<Watchers>,
    actor_id: u32,
    stream: u64,
}

impl Drop for WatcherGuard {
    fn drop(&mut self) {
        let mut table = self
            .watchers
            .by_actor
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if table
            .get(&self.actor_id)
            .is_some_and(|e| e.stream == self.stream)
        {
            table.remove(&self.actor_id);
        }
    }
}

/// What the selector process provides to its gRPC service.
pub trait SelectorBackend: Send + Sync + 'static {
    /// A fresh status snapshot (answers `Selector/GetStatus`).
    fn status(&self) -> impl Future<Output = Result<SelectorStatus, Status>> + Send;
}

/// A validated `SaveCheckpoint` request.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CheckpointRequest {
    /// `[A-Za-z0-9_-]{1,64}` when present; safe to put in a file name.
    pub label: Option<String>,
}

impl TryFrom<pb::SaveCheckpointRequest> for CheckpointRequest {
    type Error = Status;
    fn try_from(m: pb::SaveCheckpointRequest) -> Result<Self, Status> {
        if m.label.is_empty() {
            return Ok(Self { label: None });
        }
        let valid_char = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == '-';
        if m.label.len() > 64 || !m.label.chars().all(valid_char) {
            let shown: String = m.label.chars().take(80).collect();
            return Err(Status::invalid_argument(format!(
                "checkpoint label {shown:?}: use 1 to 64 characters from [A-Za-z0-9_-]"
            )));
        }
        Ok(Self {
            label: Some(m.label),
        })
    }
}

impl From<CheckpointRequest> for pb::SaveCheckpointRequest {
    fn from(d: CheckpointRequest) -> Self {
        Self {
            label: d.label.unwrap_or_default(),
        }
    }
}

/// Where a checkpoint was written.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct CheckpointSaved {
    /// Path of the written checkpoint (safetensors) as the learner sees it (never empty).
    pub path: String,
    /// SAC updates the learner had applied when it wrote the checkpoint.
    pub learner_update: u64,
    /// Version of the policy weights in the checkpoint.
    pub policy_version: u64,
}

impl TryFrom<pb::SaveCheckpointResponse> for CheckpointSaved {
    type Error = Status;
    fn try_from(m: pb::SaveCheckpointResponse) -> Result<Self, Status> {
        if m.path.is_empty() {
            return Err(Status::invalid_argument(
                "SaveCheckpointResponse: empty path",
            ));
        }
        Ok(Self {
            path: m.path,
            learner_update: m.learner_update,
            policy_version: m.policy_version,
        })
    }
}

impl From<CheckpointSaved> for pb::SaveCheckpointResponse {
    fn from(d: CheckpointSaved) -> Self {
        Self {
            path: d.path,
            learner_update: d.learner_update,
            policy_version: d.policy_version,
        }
    }
}

/// The tonic service in front of a [`LearnerBackend`].
#[derive(Debug)]
pub struct LearnerService<B> {
    backend: Arc<B>,
    shutdown: watch::Receiver<bool>,
    /// Actor id → host name and peer address of the open `WatchWeights` stream naming it.
    watchers: Arc<Watchers>,
}

type WeightsStream = Pin<Box<dyn Stream<Item = Result<pb::WeightsUpdate, Status>> + Send>>;

#[tonic::async_trait]
impl<B: LearnerBackend> Learner for LearnerService<B> {
    async fn get_status(
        &self,
        _: Request<pb::GetLearnerStatusRequest>,
    ) -> Result<Response<pb::LearnerStatus>, Status> {
        let mut status = self.backend.status().await?;
        let watchers = self
            .watchers
            .by_actor
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        for actor in &mut status.actors {
            if let Some(w) = watchers.get(&actor.actor_id) {
                actor.host.clone_from(&w.host);
                actor.address.clone_from(&w.address);
            }
        }
        drop(watchers);
        Ok(Response::new(status.into()))
    }

    type WatchWeightsStream = WeightsStream;

    async fn watch_weights(
        &self,
        request: Request<pb::WatchWeightsRequest>,
    ) -> Result<Response<WeightsStream>, Status> {
        let peer = request
            .remote_addr()
            .map(|a| a.to_string())
            .unwrap_or_default();
        let request = request.into_inner();
        let mut kinds = request
            .kinds
            .into_iter()
            .map(WeightsKind::try_from)
            .collect::<Result<Vec<_>, _>>()?;
        let guard = match request.actor_id {
            Some(actor_id) => Some(self.name_watcher(actor_id, request.host, peer)?),
            None => None,
        };
        if kinds.is_empty() {
            kinds = WeightsKind::ALL.to_vec();
        }
        kinds.sort();
        kinds.dedup();
        let hub = self.backend.weight_hub().subscribe();
        Ok(Response::new(Box::pin(weight_stream(
            hub,
            self.shutdown.clone(),
            kinds,
            guard,
        ))))
    }

    async fn save_checkpoint(
        &self,
        request: Request<pb::SaveCheckpointRequest>,
    ) -> Result<Response<pb::SaveCheckpointResponse>, Status> {
        let request = CheckpointRequest::try_from(request.into_inner())?;
        Ok(Response::new(
            self.backend.save_checkpoint(request).await?.into(),
        ))
    }
}

impl<B: LearnerBackend> LearnerService<B> {
    /// Records that `actor_id` follows the weights from `host` at `peer`, until the returned
    /// guard (held by its stream) is dropped. Refuses an oversized host name, an id that is not
    /// one of the run's actors, and a new id when the table is full.
    fn name_watcher(
        &self,
        actor_id: u32,
        host: String,
        peer: String,
    ) -> Result<WatcherGuard, Status> {
        if host.len() > crate::status::MAX_HOST_BYTES {
            return Err(Status::invalid_argument(format!(
                "host is {} bytes, the limit is {}",
                host.len(),
                crate::status::MAX_HOST_BYTES
            )));
        }
        if let Some(slots) = self.backend.actor_slots() {
            if actor_id >= slots {
                return Err(Status::invalid_argument(format!(
                    "actor id {actor_id} is not one of this run's {slots} actors (0 to {})",
                    slots.saturating_sub(1)
                )));
            }
        }
        let stream = self
            .watchers
            .next_stream
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let mut table = self
            .watchers
            .by_actor
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        if table.len() >= MAX_WATCHERS && !table.contains_key(&actor_id) {
            return Err(Status::resource_exhausted(format!(
                "{MAX_WATCHERS} named weight watchers are connected; no more are kept"
            )));
        }
        table.insert(
            actor_id,
            WatcherEntry {
                host,
                address: peer,
                stream,
            },
        );
        Ok(WatcherGuard {
            watchers: Arc::clone(&self.watchers),
            actor_id,
            stream,
        })
    }
}

struct StreamState {
    hub: watch::Receiver<Latest>,
    shutdown: watch::Receiver<bool>,
    kinds: Vec<WeightsKind>,
    sent: [u64; 3],
    pending: VecDeque<Arc<pb::WeightsUpdate>>,
    /// The stream's entry in the watcher table, removed when the stream is dropped.
    _watcher: Option<WatcherGuard>,
}

/// Latest-wins stream of weight versions: sends what is newer than what this subscriber already
/// got, then waits for the hub to change. Ends when the server shuts down or the hub is gone.
fn weight_stream(
    hub: watch::Receiver<Latest>,
    shutdown: watch::Receiver<bool>,
    kinds: Vec<WeightsKind>,
    watcher: Option<WatcherGuard>,
) -> impl Stream<Item = Result<pb::WeightsUpdate, Status>> + Send {
    let state = StreamState {
        hub,
        shutdown,
        kinds,
        sent: [0; 3],
        pending: VecDeque::new(),
        _watcher: watcher,
    };
    futures_util::stream::unfold(state, |mut s| async move {
        loop {
            if *s.shutdown.borrow() {
                return None;
            }
            if let Some(update) = s.pending.pop_front() {
                return Some((Ok(pb::WeightsUpdate::clone(&update)), s));
            }
            {
                let latest = s.hub.borrow_and_update();
                for &kind in &s.kinds {
                    if let Some(update) = latest.get(kind) {
                        if update.version > s.sent[kind.index()] {
                            s.sent[kind.index()] = update.version;
                            s.pending.push_back(Arc::clone(update));
                        }
                    }
                }
            }
            if !s.pending.is_empty() {
                continue;
            }
            tokio::select! {
                changed = s.hub.changed() => if changed.is_err() { return None },
                _ = s.shutdown.changed() => {}
            }
        }
    })
}

/// The tonic service in front of a [`SelectorBackend`].
#[derive(Debug)]
pub struct SelectorService<B> {
    backend: Arc<B>,
}

#[tonic::async_trait]
impl<B: SelectorBackend> Selector for SelectorService<B> {
    async fn get_status(
        &self,
        _: Request<pb::GetSelectorStatusRequest>,
    ) -> Result<Response<pb::SelectorStatus>, Status> {
        Ok(Response::new(self.backend.status().await?.into()))
    }
}

/// Serves `terl.v1.Learner` (+ health + reflection) on `listener` with default options until
/// `shutdown` completes.
pub async fn serve_learner<B: LearnerBackend>(
    listener: TcpListener,
    backend: B,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), ServeError> {
    serve_learner_with(listener, backend, shutdown, ServeOptions::default()).await
}

/// [`serve_learner`] with explicit options.
pub async fn serve_learner_with<B: LearnerBackend>(
    listener: TcpListener,
    backend: B,
    shutdown: impl Future<Output = ()> + Send,
    options: ServeOptions,
) -> Result<(), ServeError> {
    if backend.weight_hub().max_message_bytes() > options.max_message_bytes {
        tracing::warn!(
            hub = backend.weight_hub().max_message_bytes(),
            server = options.max_message_bytes,
            "the weight hub accepts larger versions than the server will encode"
        );
    }
    let (stop_streams, shutdown_rx) = watch::channel(false);
    let service = LearnerServer::new(LearnerService {
        backend: Arc::new(backend),
        shutdown: shutdown_rx,
        watchers: Arc::default(),
    })
    .max_decoding_message_size(options.max_message_bytes)
    .max_encoding_message_size(options.max_message_bytes);
    serve(
        listener,
        <LearnerServer<LearnerService<B>> as NamedService>::NAME,
        |router| router.add_service(service),
        shutdown,
        options,
        move || {
            let _ = stop_streams.send(true);
        },
    )
    .await
}

/// Serves `terl.v1.Selector` (+ health + reflection) on `listener` until `shutdown` completes.
pub async fn serve_selector<B: SelectorBackend>(
    listener: TcpListener,
    backend: B,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), ServeError> {
    serve_selector_with(listener, backend, shutdown, ServeOptions::default()).await
}

/// [`serve_selector`] with explicit options.
pub async fn serve_selector_with<B: SelectorBackend>(
    listener: TcpListener,
    backend: B,
    shutdown: impl Future<Output = ()> + Send,
    options: ServeOptions,
) -> Result<(), ServeError> {
    let service = SelectorServer::new(SelectorService {
        backend: Arc::new(backend),
    })
    .max_decoding_message_size(options.max_message_bytes)
    .max_encoding_message_size(options.max_message_bytes);
    serve(
        listener,
        <SelectorServer<SelectorService<B>> as NamedService>::NAME,
        |router| router.add_service(service),
        shutdown,
        options,
        || {},
    )
    .await
}

/// The router every server of this crate builds on.
pub(crate) type SecuredRouter = Router<tower_layer::Stack<AuthLayer, tower_layer::Identity>>;

/// Health + reflection v1 + reflection v1alpha, with our transport settings, TLS when
/// configured, and the token check in front of all of them.
/// Reflection lists exactly the services this server answers (`service_name`, health and both
/// reflection versions), not every service in the descriptor set.
pub(crate) fn base_router(
    options: &ServeOptions,
    service_name: &str,
    health: tonic_health::pb::health_server::HealthServer<
        impl tonic_health::pb::health_server::Health,
    >,
) -> Result<SecuredRouter, ServeError> {
    use tonic_reflection::pb::{v1, v1alpha};
    let reflection = |other_reflection_version: &'static [u8]| {
        // Each build_v1* adds its own descriptor; the other version's is added here.
        tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(other_reflection_version)
            .with_service_name(service_name)
            .with_service_name("grpc.health.v1.Health")
            .with_service_name("grpc.reflection.v1.ServerReflection")
            .with_service_name("grpc.reflection.v1alpha.ServerReflection")
    };
    let mut builder = Server::builder();
    if let Some(tls) = &options.security.tls {
        builder = builder.tls_config(tls.config())?;
    }
    Ok(builder
        .layer(options.security.layer())
        .initial_stream_window_size(options.stream_window_bytes)
        .initial_connection_window_size(options.connection_window_bytes)
        .add_service(health)
        .add_service(reflection(v1alpha::FILE_DESCRIPTOR_SET).build_v1()?)
        .add_service(reflection(v1::FILE_DESCRIPTOR_SET).build_v1alpha()?))
}

async fn serve(
    listener: TcpListener,
    service_name: &'static str,
    add_service: impl FnOnce(SecuredRouter) -> SecuredRouter,
    shutdown: impl Future<Output = ()> + Send,
    options: ServeOptions,
    on_shutdown: impl FnOnce() + Send,
) -> Result<(), ServeError> {
    let addr = listener.local_addr()?;
    options.security.check_bind(addr)?;
    let (reporter, health) = tonic_health::server::health_reporter();
    reporter
        .set_service_status(service_name, ServingStatus::Serving)
        .await;
    let router = add_service(base_router(&options, service_name, health)?);
    tracing::info!(
        %addr,
        service = service_name,
        token = options.security.token.is_some(),
        status_without_token = options.security.token.is_some()
            && options.security.status_without_token,
        tls = options.security.tls.is_some(),
        "gRPC server listening"
    );
    let (fired, fired_rx) = tokio::sync::oneshot::channel::<()>();
    let signal = async move {
        shutdown.await;
        let _ = fired.send(());
        for name in ["", service_name] {
            reporter
                .set_service_status(name, ServingStatus::NotServing)
                .await;
        }
        on_shutdown();
        tracing::info!(%addr, service = service_name, "gRPC server shutting down");
    };
    let incoming = TcpIncoming::from(listener).with_nodelay(Some(true));
    let server = router.serve_with_incoming_shutdown(incoming, signal);
    let grace_over = async {
        match fired_rx.await {
            Ok(()) => tokio::time::sleep(options.shutdown_grace).await,
            Err(_) => std::future::pending().await,
        }
    };
    tokio::select! {
        result = server => result?,
        () = grace_over => tracing::warn!(
            %addr,
            grace = ?options.shutdown_grace,
            "calls still open after the shutdown grace period; returning without them"
        ),
    }
    Ok(())
}
