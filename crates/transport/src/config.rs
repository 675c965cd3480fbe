//! Transport configuration and the iceoryx2 limits derived from it.
//!
//! iceoryx2's defaults (2 publishers, 2-sample buffers, safe overflow on) suit a demo, not
//! N actors streaming into one learner; every limit here is derived from the actor count
//! so a service created by the first process fits everyone who joins later.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::actor_to_learner::TransitionBatch;
use crate::actor_to_selector::EpisodeSummary;
use crate::channel::{Message, Topic};
use crate::error::TransportError;
use crate::flow::{OverflowPolicy, DEFAULT_BLOCK_TIMEOUT};
use crate::selector_to_learner::SelectedBatch;

/// Everything needed to open a run's shared-memory streams.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TransportConfig {
    /// Part of every service name (`terl/<run_id>/transitions`), so two clusters on one host
    /// never mix. Letters, digits, `-`, `_`, `.`; at most 64 characters.
    pub run_id: String,
    /// Actor processes (publishers of transitions and episodes).
    pub num_actors: usize,
    /// Transition batches a receiver can hold before senders meet back-pressure.
    pub buffer_batches: usize,
    /// Episodes a receiver can hold.
    pub buffer_episodes: usize,
    /// Selected batches a receiver can hold.
    pub buffer_selected: usize,
    /// What a sender does when a receiver is full.
    pub overflow: OverflowPolicy,
    /// How long a `Block` send waits before failing with `BlockTimeout`.
    #[serde(with = "secs_f64")]
    pub block_timeout: Duration,
    /// Check that `/dev/shm` has room for the run before creating anything.
    pub check_shm: bool,
    /// Which engine carries the streams (shared memory unless the run file says otherwise).
    pub transport: TransportKind,
    /// Session settings of the Zenoh transport ([`crate::zenoh_net`]); unused by shared
    /// memory.
    pub zenoh: ZenohConfig,
}

/// Which engine carries a run's streams.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TransportKind {
    /// iceoryx2 shared memory: every process on one host (the default).
    #[default]
    Shm,
    /// Zenoh over TCP: processes on several hosts.
    Zenoh,
}

/// Zenoh's role for this process.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ZenohMode {
    /// Connects directly to the peers it learns of (through `connect` and gossip).
    #[default]
    Peer,
    /// Connects only to the router or peer in `connect`; everything goes through it.
    Client,
    /// Routes between the clients and peers that connect to it (`terl zenoh-router`, or a
    /// process of the run itself); listens on `listen` (`tcp/127.0.0.1:7447` if empty).
    Router,
}

/// The Zenoh session of one process: how it finds the others.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohConfig {
    /// Peer, client or router (default: peer).
    pub mode: ZenohMode,
    /// Endpoints to listen on: `tcp/<host>:<port>` on a loopback address, or
    /// `quic/<host>:<port>`, e.g. `quic/0.0.0.0:7447` (every interface, UDP; beyond loopback only
    /// QUIC, TLS 1.3, with [`ZenohConfig::secret`] is accepted, see
    /// [`ZenohConfig::check_locked`]). Empty:
    /// loopback only (a peer on a free port of 127.0.0.1, a router on 127.0.0.1:7447, a client
    /// nowhere).
    pub listen: Vec<String>,
    /// Endpoints to connect to, e.g. `quic/10.0.0.1:7447` (the learner's host or a router).
    /// Retried until reachable.
    pub connect: Vec<String>,
    /// Find peers on the local network by UDP multicast as well (off: only `connect` and
    /// the gossip of connected peers). Refused when a session opens
    /// ([`ZenohConfig::check_locked`]): it would connect to unknown peers.
    pub multicast_scouting: bool,
    /// The run's shared secret for Zenoh's user/password authentication (every session of the
    /// run proves it holds it; one without it is refused when it opens). Not read from the run
    /// file: the services set it from the control-plane token (`TERL_TOKEN` or
    /// `cluster.token_file`). Without it every endpoint must be a loopback address.
    #[serde(skip)]
    pub secret: Option<ZenohSecret>,
    /// The TLS files of `quic/` endpoints. Not read from `[cluster.zenoh]`: the services take
    /// them from `[cluster] tls_ca`, `tls_cert` and `tls_key`, the files of the gRPC servers
    /// (`terl certs` makes them), and `terl zenoh-router` from its flags.
    #[serde(skip)]
    pub tls: ZenohTls,
}

/// The PEM files of a session's `quic/` endpoints (Zenoh's QUIC transport: quinn with rustls,
/// TLS 1.3 over UDP). Zenoh reads them when a link opens: a missing or malformed file fails
/// that listener or connection, naming the file.
///
/// Why QUIC and not Zenoh's `tls/` link: Zenoh 1.10's TLS link reads and writes one rustls
/// stream from two tasks at once through an `UnsafeCell` (eclipse-zenoh/zenoh#2557, open).
/// terl's streams are full duplex (messages one way, acknowledgements the other), and over
/// `tls/` on loopback the receiver got 3,132 of the 219,786 batches two publishers counted as
/// sent, 16 of them out of order (the bench crate's `remote_halves_count_every_batch` run over
/// `tls/`; lossless over `tcp/` and `quic/`). A QUIC link keeps a separate send and receive
/// stream.
///
/// A connecting session checks the certificate of the endpoint it dials against `ca` and the
/// host in the endpoint (a DNS name or IP address among the certificate's subject alternative
/// names). Zenoh 1.10's QUIC client also trusts the public web roots beside `ca`, so a name a
/// public authority would certify for someone else is not safe as an endpoint host; the run's
/// token (Zenoh's user/password authentication inside the encrypted link) is checked either
/// way.
/// Clients present no certificate (no mutual TLS): they prove the token instead.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ZenohTls {
    /// CA certificate(s) the `quic/` endpoints a session connects to are checked against.
    pub ca: Option<PathBuf>,
    /// Certificate chain presented on `quic/` listen endpoints (with `key`).
    pub cert: Option<PathBuf>,
    /// Private key of `cert` (PKCS#8, SEC1 or PKCS#1).
    pub key: Option<PathBuf>,
}

/// The run's shared secret as Zenoh's authentication uses it: 16 to 1024 visible ASCII
/// characters (the control-plane token's rules). `Debug` prints `ZenohSecret(<redacted>)`.
#[derive(Clone, PartialEq, Eq)]
pub struct ZenohSecret(String);

impl core::fmt::Debug for ZenohSecret {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("ZenohSecret(<redacted>)")
    }
}

impl ZenohSecret {
    /// The user name every session of a run authenticates as (Zenoh's `usrpwd` user).
    pub const USER: &'static str = "terl";

    /// Checks `value`: 16 to 1024 visible ASCII characters (no spaces, no control characters).
    ///
    /// # Errors
    /// [`TransportError::Config`] naming the rule broken, never the value.
    pub fn new(value: impl Into<String>) -> Result<Self, TransportError> {
        let value = value.into();
        if !(16..=1024).contains(&value.len()) || !value.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(TransportError::Config(
                "the Zenoh secret must be 16 to 1024 visible ASCII characters".into(),
            ));
        }
        Ok(Self(value))
    }

    /// The secret itself, for the session's authentication only.
    pub(crate) fn expose(&self) -> &str {
        &self.0
    }
}

impl ZenohConfig {
    /// Checks the endpoint syntax: `tcp/<host>:<port>` or `quic/<host>:<port>` (TCP and QUIC
    /// are built in), the port a number up to 65535, optionally followed by Zenoh's `?config` /
    /// `#metadata`. A `tls/` endpoint is refused with the reason (see [`ZenohTls`]).
    pub fn validate(&self) -> Result<(), TransportError> {
        for endpoint in self.listen.iter().chain(&self.connect) {
            if let Some(address) = endpoint.strip_prefix("tls/") {
                return Err(TransportError::Config(format!(
                    "zenoh endpoint {endpoint:?}: Zenoh's tls/ link is not built in (Zenoh 1.10 \
                     reads and writes one TLS stream from two tasks at once, \
                     eclipse-zenoh/zenoh#2557, and lost and reordered messages here): use \
                     quic/{address}, TLS 1.3 over UDP with the same certificate files"
                )));
            }
            if let Some(address) = endpoint.strip_prefix("quic/") {
                // Zenoh reads per-link settings after `?`/`#`, TLS ones included
                // (`#verify_name_on_connect=false`, another CA or key): not on an encrypted link.
                if address.contains(['?', '#']) {
                    return Err(TransportError::Config(format!(
                        "zenoh endpoint {endpoint:?}: a quic/ endpoint takes no ?config or \
                         #metadata (Zenoh would read TLS settings from it, past the run's \
                         certificate files); write quic/<host>:<port>"
                    )));
                }
                if address.starts_with('[') {
                    return Err(TransportError::Config(format!(
                        "zenoh endpoint {endpoint:?}: Zenoh 1.10's QUIC link cannot check a \
                         certificate against an IPv6 address (it keeps the brackets in the \
                         server name); use an IPv4 address or a host name"
                    )));
                }
            }
            if !endpoint_is_host_port(endpoint) {
                return Err(TransportError::Config(format!(
                    "zenoh endpoint {endpoint:?} must look like tcp/<host>:<port> or \
                     quic/<host>:<port> (TCP and QUIC are built in)"
                )));
            }
        }
        if self.mode == ZenohMode::Client && self.connect.is_empty() {
            return Err(TransportError::Config(
                "zenoh mode \"client\" needs at least one `connect` endpoint (a router or peer)"
                    .into(),
            ));
        }
        Ok(())
    }

    /// What a session checks before it opens, beyond [`ZenohConfig::validate`]:
    /// - no multicast scouting;
    /// - every endpoint beyond loopback (`127.0.0.0/8`, `[::1]`, `localhost`) is a `quic/`
    ///   one, and [`ZenohConfig::secret`] is set: beyond this host the data plane is encrypted
    ///   and every session proves the run's token, as a gRPC server beyond loopback needs the
    ///   token;
    /// - a `quic/` listen endpoint has [`ZenohTls::cert`] and [`ZenohTls::key`], a `quic/`
    ///   connect endpoint [`ZenohTls::ca`].
    ///
    /// (A run file is validated without the secret and the TLS files: the services add them
    /// when they start.)
    ///
    /// # Errors
    /// [`TransportError::Config`] naming the endpoint and the settings that would admit it.
    pub fn check_locked(&self) -> Result<(), TransportError> {
        if self.multicast_scouting {
            // Scouting connects to whatever answers on the network, and Zenoh's user/password
            // authentication is checked by the side that accepts a connection only: a session
            // that connects out to an unknown peer would let it in, token or not.
            return Err(TransportError::Config(
                "zenoh multicast_scouting connects to any peer that answers on the local \
                 network, and Zenoh's authentication checks only the side that opens a \
                 connection, so an unknown peer could join the run: name the run's peers in \
                 `connect` instead"
                    .into(),
            ));
        }
        let endpoints =
            (self.listen.iter().map(|e| (e, true))).chain(self.connect.iter().map(|e| (e, false)));
        for (endpoint, listening) in endpoints {
            let tls = endpoint.starts_with("quic/");
            if !endpoint_is_loopback(endpoint) {
                if !tls {
                    let host_port = endpoint.split_once('/').map_or("", |(_, a)| a);
                    return Err(TransportError::Config(format!(
                        "zenoh endpoint {endpoint:?} is not a loopback address, and beyond this \
                         host the Zenoh data plane runs over QUIC (TLS 1.3) only: write it \
                         quic/{host_port}, give the processes the run's certificates \
                         ([cluster] tls_ca; tls_cert and tls_key where a process listens; \
                         `terl certs` makes them; terl zenoh-router --tls-cert/--tls-key) and \
                         the run's token, or use 127.0.0.1 endpoints"
                    )));
                }
                if self.secret.is_none() {
                    return Err(TransportError::Config(format!(
                        "zenoh endpoint {endpoint:?} is not a loopback address, and a Zenoh \
                         session beyond this host needs the run's token: set the TERL_TOKEN \
                         environment variable (or the run file's cluster.token_file; terl \
                         zenoh-router --token-file) for every process of the run (sessions \
                         then authenticate with it), or use 127.0.0.1 endpoints"
                    )));
                }
            }
            if tls && listening && (self.tls.cert.is_none() || self.tls.key.is_none()) {
                return Err(TransportError::Config(format!(
                    "zenoh listen endpoint {endpoint:?} is QUIC and needs a certificate and its \
                     key: [cluster] tls_cert and tls_key (terl zenoh-router --tls-cert and \
                     --tls-key; `terl certs` makes them)"
                )));
            }
            if tls && !listening && self.tls.ca.is_none() {
                return Err(TransportError::Config(format!(
                    "zenoh connect endpoint {endpoint:?} is QUIC and needs the CA to check the \
                     certificate it is shown: [cluster] tls_ca (`terl certs` makes it)"
                )));
            }
        }
        Ok(())
    }
}

/// The endpoints a session listens on: `listen`, or when it is empty a loopback one (a peer on
/// a free port, a router on Zenoh's port 7447; a client none), never every interface.
pub(crate) fn listen_endpoints(config: &ZenohConfig) -> Vec<String> {
    match (config.listen.is_empty(), config.mode) {
        (false, _) => config.listen.clone(),
        (true, ZenohMode::Peer) => vec!["tcp/127.0.0.1:0".into()],
        (true, ZenohMode::Router) => vec!["tcp/127.0.0.1:7447".into()],
        (true, ZenohMode::Client) => vec![],
    }
}

/// Whether a `tcp/` or `quic/` endpoint names this host only: `localhost`, an IPv4 address in
/// `127.0.0.0/8` or `[::1]`.
fn endpoint_is_loopback(endpoint: &str) -> bool {
    let address = endpoint
        .strip_prefix("tcp/")
        .or_else(|| endpoint.strip_prefix("quic/"))
        .unwrap_or(endpoint);
    let address = address.split(['?', '#']).next().unwrap_or_default();
    let host = address.rsplit_once(':').map_or(address, |(h, _)| h);
    let host = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host);
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// `tcp/<host>:<port>[?...][#...]` or the same with `quic/`, with a non-empty host (a name, an
/// IPv4 address or a bracketed IPv6 address) and a port in 0..=65535.
fn endpoint_is_host_port(endpoint: &str) -> bool {
    let Some(address) = endpoint
        .strip_prefix("tcp/")
        .or_else(|| endpoint.strip_prefix("quic/"))
    else {
        return false;
    };
    let address = address.split(['?', '#']).next().unwrap_or_default();
    let Some((host, port)) = address.rsplit_once(':') else {
        return false;
    };
    let host_ok = if let Some(inner) = host.strip_prefix('[') {
        inner.strip_suffix(']').is_some_and(|h| !h.is_empty())
    } else {
        !host.is_empty() && !host.contains([':', '[', ']', '/'])
    };
    host_ok
        && !port.is_empty()
        && port.bytes().all(|b| b.is_ascii_digit())
        && port.parse::<u16>().is_ok()
}

impl Default for TransportConfig {
    fn default() -> Self {
        Self {
            run_id: "default".into(),
            num_actors: 1,
            buffer_batches: 64,
            buffer_episodes: 8,
            buffer_selected: 8,
            overflow: OverflowPolicy::Block,
            block_timeout: DEFAULT_BLOCK_TIMEOUT,
            check_shm: true,
            transport: TransportKind::Shm,
            zenoh: ZenohConfig::default(),
        }
    }
}

/// iceoryx2 limits of one service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ServiceLimits {
    /// Publishers the service admits (iceoryx2 `max_publishers`): the senders plus spares for
    /// restarts and tools.
    pub max_publishers: usize,
    /// Subscribers the service admits (iceoryx2 `max_subscribers`).
    pub max_subscribers: usize,
    /// Nodes that may open the service (iceoryx2 `max_nodes`): actors, learner, selector and
    /// spares.
    pub max_nodes: usize,
    /// Messages each subscriber's queue holds (iceoryx2 `subscriber_max_buffer_size`).
    pub subscriber_buffer: usize,
}

/// Samples a subscriber holds at once: we copy out and release immediately.
pub(crate) const SUBSCRIBER_MAX_BORROWED: usize = 1;
/// Samples a publisher holds at once: loan, write, send.
pub(crate) const PUBLISHER_MAX_LOANED: usize = 1;
/// Slack in the publisher table for a process restarting while its predecessor is not yet
/// cleaned up, and for tools (benchmarks, taps).
const SPARE_PUBLISHERS: usize = 2;
/// Per-sample header iceoryx2 adds (generous upper bound).
const SAMPLE_HEADER_BYTES: usize = 128;

impl TransportConfig {
    /// A config for `run_id` with defaults otherwise.
    pub fn new(run_id: impl Into<String>, num_actors: usize) -> Self {
        Self {
            run_id: run_id.into(),
            num_actors,
            ..Self::default()
        }
    }

    /// Checks the run id (1 to 64 characters of `[A-Za-z0-9._-]`), `num_actors ≥ 1` and every
    /// buffer size ≥ 1; otherwise [`TransportError::Config`].
    pub fn validate(&self) -> Result<(), TransportError> {
        let id = &self.run_id;
        if id.is_empty()
            || id == "."
            || id == ".."
            || id.len() > 64
            || !id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err(TransportError::Config(format!(
                "run_id {id:?} must be 1..=64 characters of [A-Za-z0-9._-], not . or .."
            )));
        }
        if self.num_actors == 0 {
            return Err(TransportError::Config("num_actors must be ≥ 1".into()));
        }
        for (name, value) in [
            ("buffer_batches", self.buffer_batches),
            ("buffer_episodes", self.buffer_episodes),
            ("buffer_selected", self.buffer_selected),
        ] {
            if value == 0 {
                return Err(TransportError::Config(format!("{name} must be ≥ 1")));
            }
        }
        Ok(())
    }

    /// `terl/<run_id>/<topic>`.
    pub fn service_name(&self, topic: Topic) -> String {
        format!("terl/{}/{}", self.run_id, topic.name())
    }

    /// Limits for `topic`. Transitions: every actor publishes, the learner subscribes.
    /// Episodes: every actor publishes, selector and learner subscribe. Selected: the
    /// selector publishes, the learner subscribes.
    pub fn limits(&self, topic: Topic) -> ServiceLimits {
        let actors = self.num_actors;
        let (max_publishers, max_subscribers, subscriber_buffer) = match topic {
            Topic::Transitions => (actors + SPARE_PUBLISHERS, 1, self.buffer_batches),
            Topic::Episodes => (actors + SPARE_PUBLISHERS, 2, self.buffer_episodes),
            Topic::Selected => (1 + SPARE_PUBLISHERS, 1, self.buffer_selected),
        };
        ServiceLimits {
            max_publishers,
            max_subscribers,
            // actors + learner + selector, plus room for restarts and tools
            max_nodes: actors + 2 + 2 * SPARE_PUBLISHERS,
            subscriber_buffer,
        }
    }

    /// Bytes of one publisher's data segment on `topic`, as iceoryx2 sizes it.
    pub fn publisher_segment_bytes<M: Message>(&self) -> u64 {
        let l = self.limits(M::TOPIC);
        let samples = l.max_subscribers * (l.subscriber_buffer + SUBSCRIBER_MAX_BORROWED)
            + PUBLISHER_MAX_LOANED;
        (samples * (core::mem::size_of::<M>() + SAMPLE_HEADER_BYTES)) as u64
    }

    /// Shared memory the whole run needs: each actor's transition and episode segments, the
    /// selector's segment, plus a margin for iceoryx2's management segments.
    pub fn required_shm_bytes(&self) -> u64 {
        let per_actor = self.publisher_segment_bytes::<TransitionBatch>()
            + self.publisher_segment_bytes::<EpisodeSummary>();
        let total =
            self.num_actors as u64 * per_actor + self.publisher_segment_bytes::<SelectedBatch>();
        total + total / 10 + (8 << 20)
    }
}

mod secs_f64 {
    use std::time::Duration;

    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(d.as_secs_f64())
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Duration, D::Error> {
        let secs = f64::deserialize(d)?;
        Duration::try_from_secs_f64(secs).map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_run_ids_and_zero_sizes() {
        assert!(TransportConfig::new("run-1_a.b", 2).validate().is_ok());
        for bad in ["", "a/b", "has space", &"x".repeat(65)] {
            assert!(TransportConfig::new(bad, 1).validate().is_err(), "{bad:?}");
        }
        assert!(TransportConfig::new("r", 0).validate().is_err());
        let cfg = TransportConfig {
            buffer_batches: 0,
            ..TransportConfig::new("r", 1)
        };
        assert!(cfg.validate().is_err());
    }

    #[test]
    fn zenoh_endpoints_need_tcp_or_quic_host_and_port() {
        let with = |endpoint: &str| ZenohConfig {
            listen: vec![endpoint.to_string()],
            ..ZenohConfig::default()
        };
        for good in [
            "tcp/0.0.0.0:7447",
            "tcp/terl-zenoh:7447",
            "tcp/[::1]:0",
            "tcp/10.0.0.1:65535",
            "tcp/[fe80::1]:7447#iface=eth0",
            "quic/terl-zenoh:7447",
            "quic/10.0.0.1:7447",
        ] {
            assert!(with(good).validate().is_ok(), "{good}");
        }
        for bad in [
            "",
            "tcp/",
            "quic/",
            "udp/0.0.0.0:7447",
            "tcp/tls/0.0.0.0:7447",
            "tcp/127.0.0.1:99999",
            "tcp/127.0.0.1",
            "tcp/:7447",
            "quic/:7447",
            "tcp/127.0.0.1:",
            "tcp/127.0.0.1:74x7",
            "tcp/::1:7447",
            "tcp/[]:7447",
        ] {
            let err = with(bad).validate().unwrap_err().to_string();
            assert!(err.contains("tcp/<host>:<port>"), "{bad:?}: {err}");
        }
        // No per-link settings and no IPv6 literal on a quic/ endpoint.
        for bad in [
            "quic/10.0.0.1:7447#verify_name_on_connect=false",
            "quic/10.0.0.1:7447?root_ca_certificate_file=/tmp/ca.pem",
            "quic/[::1]:7447",
        ] {
            assert!(with(bad).validate().is_err(), "{bad}");
        }
        // Zenoh's TLS link: refused with the reason and the endpoint to write instead.
        let err = with("tls/10.0.0.1:7447")
            .validate()
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("#2557") && err.contains("quic/10.0.0.1:7447"),
            "{err}"
        );
    }

    fn run_tls() -> ZenohTls {
        ZenohTls {
            ca: Some("ca.pem".into()),
            cert: Some("cert.pem".into()),
            key: Some("key.pem".into()),
        }
    }

    #[test]
    fn endpoints_beyond_this_host_need_quic_and_the_secret() {
        let secret = ZenohSecret::new("0123456789abcdef").unwrap();
        for (host_port, loopback) in [
            ("127.0.0.1:7447", true),
            ("127.9.0.3:0", true),
            ("localhost:7447", true),
            ("LOCALHOST:7447", true),
            ("[::1]:7447#iface=lo", true),
            ("0.0.0.0:7447", false),
            ("[::]:7447", false),
            ("10.0.0.1:7447", false),
            ("terl-zenoh:7447", false),
            ("localhost.example:7447", false),
            ("128.0.0.1:7447", false),
        ] {
            let (tcp, tls) = (format!("tcp/{host_port}"), format!("quic/{host_port}"));
            for listening in [true, false] {
                let with = |endpoint: &str| {
                    let e = vec![endpoint.to_string()];
                    let (listen, connect) = if listening { (e, vec![]) } else { (vec![], e) };
                    ZenohConfig {
                        listen,
                        connect,
                        ..ZenohConfig::default()
                    }
                };
                // Plain TCP: on loopback as it is, beyond it never, token and files or not.
                let open = with(&tcp);
                assert!(open.validate().is_ok(), "{tcp}: a run file may name it");
                let locked = ZenohConfig {
                    secret: Some(secret.clone()),
                    tls: run_tls(),
                    ..open.clone()
                };
                for config in [&open, &locked] {
                    match config.check_locked() {
                        Ok(()) => assert!(loopback, "{tcp} beyond loopback"),
                        Err(e) => {
                            assert!(!loopback, "{tcp}: {e}");
                            let e = e.to_string();
                            assert!(e.contains(&tcp) && e.contains(&tls), "{e}");
                            assert!(e.contains("tls_ca") && e.contains("token"), "{e}");
                        }
                    }
                }
                // QUIC: beyond loopback with the secret only; anywhere with the files of its
                // side (the listener's certificate and key, the connector's CA).
                let full = ZenohConfig {
                    secret: Some(secret.clone()),
                    tls: run_tls(),
                    ..with(&tls)
                };
                assert!(full.check_locked().is_ok(), "{tls}");
                let no_secret = ZenohConfig {
                    secret: None,
                    ..full.clone()
                };
                match no_secret.check_locked() {
                    Ok(()) => assert!(loopback, "{tls} without the secret"),
                    Err(e) => assert!(!loopback && e.to_string().contains("TERL_TOKEN"), "{e}"),
                }
                let missing = if listening {
                    [
                        ZenohTls {
                            cert: None,
                            ..run_tls()
                        },
                        ZenohTls {
                            key: None,
                            ..run_tls()
                        },
                    ]
                } else {
                    [
                        ZenohTls {
                            ca: None,
                            ..run_tls()
                        },
                        ZenohTls {
                            ca: None,
                            cert: None,
                            key: None,
                        },
                    ]
                };
                for tls_files in missing {
                    let e = ZenohConfig {
                        tls: tls_files.clone(),
                        ..full.clone()
                    }
                    .check_locked()
                    .unwrap_err()
                    .to_string();
                    let named = if listening { "tls_cert" } else { "tls_ca" };
                    assert!(e.contains(&tls) && e.contains(named), "{tls_files:?}: {e}");
                }
                // The other side's files are not needed.
                let own_side = if listening {
                    ZenohTls {
                        ca: None,
                        ..run_tls()
                    }
                } else {
                    ZenohTls {
                        ca: run_tls().ca,
                        ..ZenohTls::default()
                    }
                };
                assert!(ZenohConfig {
                    tls: own_side,
                    ..full.clone()
                }
                .check_locked()
                .is_ok());
            }
        }
    }

    #[test]
    fn scouting_is_refused_and_the_default_listens_on_loopback() {
        let secret = ZenohSecret::new("0123456789abcdef").unwrap();
        // Multicast scouting would connect to whatever answers: refused, token or not.
        for secret in [None, Some(secret.clone())] {
            let scouting = ZenohConfig {
                multicast_scouting: true,
                secret,
                ..ZenohConfig::default()
            };
            let e = scouting.check_locked().unwrap_err().to_string();
            assert!(e.contains("multicast_scouting"), "{e}");
        }
        // The default listens on loopback only, whatever the mode.
        for mode in [ZenohMode::Peer, ZenohMode::Router, ZenohMode::Client] {
            let config = ZenohConfig {
                mode,
                ..ZenohConfig::default()
            };
            assert!(listen_endpoints(&config)
                .iter()
                .all(|e| endpoint_is_loopback(e)));
        }
    }

    #[test]
    fn the_secret_is_checked_and_never_printed() {
        let value = "0123456789abcdef-secret";
        let secret = ZenohSecret::new(value).unwrap();
        let config = ZenohConfig {
            secret: Some(secret),
            ..ZenohConfig::default()
        };
        assert!(!format!("{config:?}").contains(value));
        assert!(!serde_json::to_string(&config).unwrap().contains(value));
        assert!(ZenohSecret::new("").is_err());
        for bad in ["short", "has a space 0123456789", "tab\t0123456789abcdef"] {
            let e = ZenohSecret::new(bad).unwrap_err().to_string();
            assert!(!e.contains(bad), "{e}");
        }
        assert!(ZenohSecret::new("x".repeat(1025)).is_err());
        assert!(ZenohSecret::new("x".repeat(1024)).is_ok());
    }

    #[test]
    fn limits_scale_with_actors() {
        let cfg = TransportConfig::new("r", 12);
        let t = cfg.limits(Topic::Transitions);
        assert!(t.max_publishers >= 12 && t.max_nodes >= 14);
        assert_eq!(t.subscriber_buffer, 64);
        assert_eq!(cfg.limits(Topic::Episodes).max_subscribers, 2);
        assert_eq!(cfg.service_name(Topic::Selected), "terl/r/selected");
    }

    #[test]
    fn shm_estimate_grows_with_actors_and_fits_default_docker_for_small_runs() {
        let small = TransportConfig::new("r", 2).required_shm_bytes();
        let large = TransportConfig::new("r", 32).required_shm_bytes();
        assert!(small < 64 << 20, "small run needs {small}");
        assert!(large > small * 4, "{large} vs {small}");
    }

    #[test]
    fn config_round_trips_through_toml_like_serde() {
        let cfg = TransportConfig::new("abc", 3);
        let json = serde_json::to_string(&cfg).unwrap();
        let back: TransportConfig = serde_json::from_str(&json).unwrap();
        assert_eq!(back, cfg);
    }
}
