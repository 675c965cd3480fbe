//! Clients of the learner and selector services that speak domain types.
//!
//! Every response passes the same `TryFrom` validation the servers apply to requests, so callers
//! (actors, the selector, `terl status`) only ever see checked values.

use std::pin::Pin;

use futures_util::{Stream, StreamExt};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::{Channel, Endpoint};
use tonic::Status;

use crate::pb;
use crate::pb::learner_client::LearnerClient as RawLearnerClient;
use crate::pb::selector_client::SelectorClient as RawSelectorClient;
use crate::security::{ClientSecurity, TokenInterceptor};
use crate::server::{CheckpointRequest, CheckpointSaved};
use crate::status::{LearnerStatus, SelectorStatus};
use crate::weights::{Weights, WeightsKind};
use crate::DEFAULT_MAX_MESSAGE_BYTES;

/// Why a connection could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    /// The address is neither `host:port` nor a valid URI.
    #[error("invalid server address {addr:?}: {source}")]
    Address {
        /// The address as given.
        addr: String,
        /// tonic's parse error.
        source: tonic::transport::Error,
    },
    /// The TCP (or TLS) connection could not be established. The message gives the error's
    /// causes once each (tonic and hyper repeat "transport error" and "tcp connect error") and,
    /// for a plaintext client whose server closed the connection, the likely reason: a server
    /// with TLS.
    #[error("cannot connect to {addr}: {}{}", causes(.error), tls_hint(.error, *.plaintext))]
    Connect {
        /// The address as given.
        addr: String,
        /// tonic's transport error (its causes are in the message).
        error: tonic::transport::Error,
        /// The client spoke plaintext HTTP/2 (no `cluster.tls_ca`).
        plaintext: bool,
    },
    /// A TLS CA is configured but the address is a plaintext `http://` URI.
    #[error(
        "{addr}: TLS is configured (cluster.tls_ca), so the address must be host:port or an \
         https:// URI, not plaintext http://"
    )]
    PlaintextWithTls {
        /// The address as given.
        addr: String,
    },
    /// tonic rejected the TLS configuration for this endpoint.
    #[error("TLS settings for {addr}: {source}")]
    Tls {
        /// The address as given.
        addr: String,
        /// tonic's error.
        source: tonic::transport::Error,
    },
}

/// An error and its sources as `a: b: c`, each distinct message once: tonic's transport
/// error wraps hyper's, which wraps the connector's, several of them saying the same thing.
pub fn causes(error: &(dyn std::error::Error + 'static)) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut next = Some(error);
    while let Some(e) = next {
        let text = e.to_string();
        // A message that repeats one already given, or that already contains the next one's
        // text (some errors print their source), adds nothing.
        if !text.is_empty() && !parts.iter().any(|p| p == &text) {
            parts.push(text);
        }
        next = e.source();
    }
    // An inner message that an outer one already ends with (it printed its source) is dropped;
    // the outer, fuller one stays.
    let mut kept: Vec<&str> = Vec::new();
    for (i, p) in parts.iter().enumerate() {
        if !parts[..i].iter().any(|outer| outer.ends_with(p.as_str())) {
            kept.push(p);
        }
    }
    kept.join(": ")
}

/// The likely reason when a plaintext client's server closed the connection at once.
fn tls_hint(error: &tonic::transport::Error, plaintext: bool) -> &'static str {
    let text = causes(error).to_lowercase();
    let closed = [
        "connection closed",
        "connection reset",
        "broken pipe",
        "h2 protocol",
        "eof",
    ]
    .iter()
    .any(|s| text.contains(s));
    if plaintext && closed {
        " (the server closed the connection: if it uses TLS, give its CA with cluster.tls_ca \
         in the run file)"
    } else {
        ""
    }
}

/// The transport under every wire client: a channel that adds the token (if any) to each call.
pub type SecuredChannel = InterceptedService<Channel, TokenInterceptor>;

/// Client settings.
#[derive(Debug, Clone)]
pub struct ClientOptions {
    /// Largest message decoded or encoded; must be at least the server's weight size.
    pub max_message_bytes: usize,
    /// Token sent on every call and TLS trust (default: neither).
    pub security: ClientSecurity,
    /// Who follows the weights, for the learner's status: an actor's id and host name
    /// ([`LearnerClient::watch_weights`] sends them; `None` for other clients).
    pub watcher: Option<Watcher>,
}

/// An actor naming itself when it subscribes to the weights; the learner lists its host and
/// address beside its stats (`terl status`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Watcher {
    /// The actor's id (`terl-actor --actor-id`).
    pub actor_id: u32,
    /// At most `MAX_HOST_BYTES` (`status.rs`) bytes (longer names are cut).
    pub host: String,
}

impl Default for ClientOptions {
    fn default() -> Self {
        Self {
            max_message_bytes: DEFAULT_MAX_MESSAGE_BYTES,
            security: ClientSecurity::default(),
            watcher: None,
        }
    }
}

impl ClientOptions {
    /// Default limits with these credentials.
    pub fn secured(security: ClientSecurity) -> Self {
        Self {
            security,
            ..Self::default()
        }
    }
}

/// Validated weight versions, in increasing version order per kind (with gaps when this
/// subscriber was slower than the publisher). An `Err` item is either a transport failure or an
/// `invalid_argument` for a message that failed validation; the stream ends when the server shuts
/// down, after which an actor reconnects.
pub type WeightsStream = Pin<Box<dyn Stream<Item = Result<Weights, Status>> + Send>>;

async fn channel(addr: &str, security: &ClientSecurity) -> Result<SecuredChannel, ConnectError> {
    let tls = security.tls.as_ref();
    let uri = if addr.contains("://") {
        if tls.is_some() && !addr.starts_with("https://") {
            return Err(ConnectError::PlaintextWithTls {
                addr: addr.to_owned(),
            });
        }
        addr.to_owned()
    } else if tls.is_some() {
        format!("https://{addr}")
    } else {
        format!("http://{addr}")
    };
    let mut endpoint = Endpoint::from_shared(uri).map_err(|source| ConnectError::Address {
        addr: addr.to_owned(),
        source,
    })?;
    if let Some(tls) = tls {
        endpoint = endpoint
            .tls_config(tls.config())
            .map_err(|source| ConnectError::Tls {
                addr: addr.to_owned(),
                source,
            })?;
    }
    let channel = endpoint
        .tcp_nodelay(true)
        // Large windows so a whole weight version is in flight at once.
        .initial_stream_window_size(4 << 20)
        .initial_connection_window_size(16 << 20)
        // Lets the server send a weight version in a few large HTTP/2 frames instead of ~90
        // frames of the 16 KiB default; measurably lowers broadcast latency.
        .max_frame_size(1 << 20)
        .connect()
        .await
        .map_err(|error| ConnectError::Connect {
            addr: addr.to_owned(),
            error,
            plaintext: tls.is_none(),
        })?;
    Ok(InterceptedService::new(
        channel,
        TokenInterceptor::new(security.token.as_ref()),
    ))
}

/// Connects to a learner at `addr` (`host:port` or a URI) with default options.
pub async fn connect_learner(addr: &str) -> Result<LearnerClient, ConnectError> {
    connect_learner_with(addr, ClientOptions::default()).await
}

/// [`connect_learner`] with explicit options.
pub async fn connect_learner_with(
    addr: &str,
    options: ClientOptions,
) -> Result<LearnerClient, ConnectError> {
    let raw = RawLearnerClient::new(channel(addr, &options.security).await?)
        .max_decoding_message_size(options.max_message_bytes)
        .max_encoding_message_size(options.max_message_bytes);
    Ok(LearnerClient {
        raw,
        watcher: options.watcher,
    })
}

/// Connects to a selector at `addr`.
pub async fn connect_selector(addr: &str) -> Result<SelectorClient, ConnectError> {
    connect_selector_with(addr, ClientOptions::default()).await
}

/// [`connect_selector`] with explicit options.
pub async fn connect_selector_with(
    addr: &str,
    options: ClientOptions,
) -> Result<SelectorClient, ConnectError> {
    let raw = RawSelectorClient::new(channel(addr, &options.security).await?)
        .max_decoding_message_size(options.max_message_bytes)
        .max_encoding_message_size(options.max_message_bytes);
    Ok(SelectorClient { raw })
}

/// The `grpc.health.v1` service name of the learner's server.
pub const LEARNER_SERVICE: &str = "terl.v1.Learner";
/// The `grpc.health.v1` service name of the selector's server.
pub const SELECTOR_SERVICE: &str = "terl.v1.Selector";

/// Why a health check gave no answer.
#[derive(Debug, thiserror::Error)]
pub enum HealthError {
    /// No connection to the server.
    #[error(transparent)]
    Connect(#[from] ConnectError),
    /// The `Health/Check` call failed (e.g. `NOT_FOUND` for an unknown service, `UNAUTHENTICATED`
    /// for a missing token).
    #[error("health check of {service:?} at {addr}: {status}")]
    Rpc {
        /// The server's address as given.
        addr: String,
        /// The service asked about.
        service: String,
        /// The gRPC status of the failed call.
        status: Status,
    },
}

/// Asks the server at `addr` (`host:port` or a URI) whether `service` (e.g.
/// [`LEARNER_SERVICE`]; `""` for the server as a whole) is serving: one
/// `grpc.health.v1.Health/Check` with `options`' token and TLS trust.
///
/// Returns `Ok(true)` for SERVING, `Ok(false)` for any other status (NOT_SERVING while a server
/// shuts down).
///
/// # Errors
/// No connection ([`HealthError::Connect`]), or the call failed ([`HealthError::Rpc`]:
/// `not_found` for a service the server does not serve, `unauthenticated` for a missing token
/// where health is not open).
pub async fn check_health(
    addr: &str,
    service: &str,
    options: &ClientOptions,
) -> Result<bool, HealthError> {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};
    let mut client = HealthClient::new(channel(addr, &options.security).await?);
    let reply = client
        .check(HealthCheckRequest {
            service: service.to_owned(),
        })
        .await
        .map_err(|status| HealthError::Rpc {
            addr: addr.to_owned(),
            service: service.to_owned(),
            status,
        })?;
    Ok(reply.into_inner().status() == ServingStatus::Serving)
}

/// A `terl.v1.Learner` client; cheap to clone (clones share the connection).
#[derive(Debug, Clone)]
pub struct LearnerClient {
    raw: RawLearnerClient<SecuredChannel>,
    watcher: Option<Watcher>,
}

impl LearnerClient {
    /// The learner's status (`Learner/GetStatus`), validated into the domain type.
    ///
    /// # Errors
    /// The call's gRPC status, or `INVALID_ARGUMENT` if the response fails validation.
    pub async fn status(&mut self) -> Result<LearnerStatus, Status> {
        let response = self.raw.get_status(pb::GetLearnerStatusRequest {}).await?;
        LearnerStatus::try_from(response.into_inner())
    }

    /// Subscribes to the given kinds (empty = all). The first items are the current version of
    /// each kind that has one; then every version the subscriber keeps up with (latest wins).
    /// Names the actor of [`ClientOptions::watcher`], if any, to the learner.
    pub async fn watch_weights(&mut self, kinds: &[WeightsKind]) -> Result<WeightsStream, Status> {
        let request = pb::WatchWeightsRequest {
            kinds: kinds
                .iter()
                .map(|&k| pb::WeightsKind::from(k) as i32)
                .collect(),
            actor_id: self.watcher.as_ref().map(|w| w.actor_id),
            host: self
                .watcher
                .as_ref()
                .map(|w| cut_to_bytes(&w.host, crate::status::MAX_HOST_BYTES))
                .unwrap_or_default(),
        };
        let stream = self.raw.watch_weights(request).await?.into_inner();
        Ok(Box::pin(
            stream.map(|item| item.and_then(Weights::try_from)),
        ))
    }

    /// Asks the learner to write a checkpoint now.
    pub async fn save_checkpoint(
        &mut self,
        request: CheckpointRequest,
    ) -> Result<CheckpointSaved, Status> {
        let response = self
            .raw
            .save_checkpoint(pb::SaveCheckpointRequest::from(request))
            .await?;
        CheckpointSaved::try_from(response.into_inner())
    }

    /// The generated client, for calls that have no domain wrapper.
    pub fn raw(&mut self) -> &mut RawLearnerClient<SecuredChannel> {
        &mut self.raw
    }
}

/// `s` cut at a character boundary to at most `max` bytes.
fn cut_to_bytes(s: &str, max: usize) -> String {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    s[..end].to_owned()
}

/// A `terl.v1.Selector` client.
#[derive(Debug, Clone)]
pub struct SelectorClient {
    raw: RawSelectorClient<SecuredChannel>,
}

impl SelectorClient {
    /// The selector's status (`Selector/GetStatus`), validated into the domain type.
    ///
    /// # Errors
    /// The call's gRPC status, or `INVALID_ARGUMENT` if the response fails validation.
    pub async fn status(&mut self) -> Result<SelectorStatus, Status> {
        let response = self.raw.get_status(pb::GetSelectorStatusRequest {}).await?;
        SelectorStatus::try_from(response.into_inner())
    }

    /// The generated client, for calls that have no domain wrapper.
    pub fn raw(&mut self) -> &mut RawSelectorClient<SecuredChannel> {
        &mut self.raw
    }
}

/// Follows the learner's weight stream for `kinds` forever: connects, hands every version to
/// `sink`, and reconnects after a failure or when the learner goes away (waiting 0.25 s, doubled
/// up to 5 s while it stays away; the first wait and every stream error are logged once). For
/// the actors and the selector, which must keep working while the learner restarts. Cancel by
/// dropping/aborting the future.
pub async fn follow_weights(addr: String, kinds: Vec<WeightsKind>, sink: impl FnMut(Weights)) {
    follow_weights_with(addr, kinds, ClientOptions::default(), sink).await
}

/// [`follow_weights`] with explicit client options: a message limit matching the learner's,
/// the token and TLS trust. A refused call (e.g. `UNAUTHENTICATED` for a wrong token) is logged
/// once per status code and retried like any other failure.
pub async fn follow_weights_with(
    addr: String,
    kinds: Vec<WeightsKind>,
    options: ClientOptions,
    mut sink: impl FnMut(Weights),
) {
    let mut logged_wait = false;
    let mut backoff = FOLLOW_BACKOFF_MIN;
    // A refusal (e.g. a wrong token) repeats every retry: log each distinct code once.
    let mut logged_refusal = None;
    loop {
        match connect_learner_with(&addr, options.clone()).await {
            Ok(mut client) => match client.watch_weights(&kinds).await {
                Ok(mut stream) => {
                    tracing::info!(%addr, ?kinds, "following the learner's weights");
                    logged_wait = false;
                    logged_refusal = None;
                    backoff = FOLLOW_BACKOFF_MIN;
                    while let Some(item) = futures_util::StreamExt::next(&mut stream).await {
                        match item {
                            Ok(weights) => sink(weights),
                            Err(status) => {
                                tracing::warn!(%status, "weights stream error");
                                break;
                            }
                        }
                    }
                }
                Err(status) => {
                    if logged_refusal != Some(status.code()) {
                        tracing::warn!(%status, "WatchWeights refused; retrying with back-off");
                        logged_refusal = Some(status.code());
                    }
                }
            },
            Err(e) => {
                if !logged_wait {
                    tracing::info!("waiting for the learner: {e}");
                    logged_wait = true;
                }
            }
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(FOLLOW_BACKOFF_MAX);
    }
}

/// [`follow_weights`]' wait before reconnecting: doubled after each failed attempt from the
/// first to the last, and back to the first once a stream is open.
const FOLLOW_BACKOFF_MIN: std::time::Duration = std::time::Duration::from_millis(250);
const FOLLOW_BACKOFF_MAX: std::time::Duration = std::time::Duration::from_secs(5);
