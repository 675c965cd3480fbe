//! Transport configuration and the iceoryx2 limits derived from it.
//!
//! iceoryx2's defaults (2 publishers, 2-sample buffers, safe overflow on) suit a demo, not
//! N actors streaming into one learner; every limit here is derived from the actor count
//! so a service created by the first process fits everyone who joins later.

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
    /// Endpoints to listen on, e.g. `tcp/0.0.0.0:7447` (every interface: needs
    /// [`ZenohConfig::secret`]). Empty: loopback only (a peer on a free port of 127.0.0.1, a
    /// router on 127.0.0.1:7447, a client nowhere).
    pub listen: Vec<String>,
    /// Endpoints to connect to, e.g. `tcp/10.0.0.1:7447` (the learner's host or a router).
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
    /// Checks the endpoint syntax: `tcp/<host>:<port>` (only TCP is built in), the port a
    /// number up to 65535, optionally followed by Zenoh's `?config` / `#metadata`.
    pub fn validate(&self) -> Result<(), TransportError> {
        for endpoint in self.listen.iter().chain(&self.connect) {
            if !endpoint_is_tcp_host_port(endpoint) {
                return Err(TransportError::Config(format!(
                    "zenoh endpoint {endpoint:?} must look like tcp/<host>:<port> (only TCP is \
                     built in)"
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

    /// What a session checks before it opens, beyond [`ZenohConfig::validate`]: no multicast
    /// scouting, and every endpoint a loopback address (`127.0.0.0/8`, `[::1]`, `localhost`)
    /// unless [`ZenohConfig::secret`] is set. (A run file is validated without it: the services add
    /// the token when they start.)
    ///
    /// # Errors
    /// [`TransportError::Config`] naming the first endpoint beyond loopback and `TERL_TOKEN`.
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
        if self.secret.is_some() {
            return Ok(());
        }
        match self
            .listen
            .iter()
            .chain(&self.connect)
            .find(|e| !endpoint_is_loopback(e))
        {
            Some(endpoint) => Err(TransportError::Config(format!(
                "zenoh endpoint {endpoint:?} is not a loopback address, and a Zenoh session \
                 beyond this host needs the run's token: set the TERL_TOKEN environment \
                 variable (or the run file's cluster.token_file; terl zenoh-router \
                 --token-file) for every process of the run (sessions then authenticate with \
                 it), or use 127.0.0.1 endpoints"
            ))),
            None => Ok(()),
        }
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

/// Whether a `tcp/<host>:<port>` endpoint names this host only: `localhost`, an IPv4 address
/// in `127.0.0.0/8` or `[::1]`.
fn endpoint_is_loopback(endpoint: &str) -> bool {
    let address = endpoint.strip_prefix("tcp/").unwrap_or(endpoint);
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

/// `tcp/<host>:<port>[?...][#...]` with a non-empty host (a name, an IPv4 address or a
/// bracketed IPv6 address) and a port in 0..=65535.
fn endpoint_is_tcp_host_port(endpoint: &str) -> bool {
    let Some(address) = endpoint.strip_prefix("tcp/") else {
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
            || id.len() > 64
            || !id
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        {
            return Err(TransportError::Config(format!(
                "run_id {id:?} must be 1..=64 characters of [A-Za-z0-9._-]"
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
    fn zenoh_endpoints_need_tcp_host_and_port() {
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
        ] {
            assert!(with(good).validate().is_ok(), "{good}");
        }
        for bad in [
            "",
            "tcp/",
            "udp/0.0.0.0:7447",
            "tcp/127.0.0.1:99999",
            "tcp/127.0.0.1",
            "tcp/:7447",
            "tcp/127.0.0.1:",
            "tcp/127.0.0.1:74x7",
            "tcp/::1:7447",
            "tcp/[]:7447",
        ] {
            let err = with(bad).validate().unwrap_err().to_string();
            assert!(err.contains("tcp/<host>:<port>"), "{bad:?}: {err}");
        }
    }

    #[test]
    fn endpoints_beyond_this_host_need_the_secret() {
        let secret = ZenohSecret::new("0123456789abcdef").unwrap();
        for (endpoint, loopback) in [
            ("tcp/127.0.0.1:7447", true),
            ("tcp/127.9.0.3:0", true),
            ("tcp/localhost:7447", true),
            ("tcp/LOCALHOST:7447", true),
            ("tcp/[::1]:7447#iface=lo", true),
            ("tcp/0.0.0.0:7447", false),
            ("tcp/[::]:7447", false),
            ("tcp/10.0.0.1:7447", false),
            ("tcp/terl-zenoh:7447", false),
            ("tcp/localhost.example:7447", false),
            ("tcp/128.0.0.1:7447", false),
        ] {
            for (listen, connect) in [
                (vec![endpoint.to_string()], vec![]),
                (vec![], vec![endpoint.to_string()]),
            ] {
                let open = ZenohConfig {
                    listen,
                    connect,
                    ..ZenohConfig::default()
                };
                assert!(
                    open.validate().is_ok(),
                    "{endpoint}: a run file may name it"
                );
                match open.check_locked() {
                    Ok(()) => assert!(loopback, "{endpoint} needs the secret"),
                    Err(e) => {
                        assert!(!loopback, "{endpoint}: {e}");
                        let e = e.to_string();
                        assert!(e.contains("TERL_TOKEN") && e.contains(endpoint), "{e}");
                    }
                }
                let locked = ZenohConfig {
                    secret: Some(secret.clone()),
                    ..open
                };
                assert!(locked.check_locked().is_ok(), "{endpoint}");
            }
        }
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
