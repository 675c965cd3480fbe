//! The Zenoh implementation of the transport seam: the same streams between processes on
//! different hosts, over TCP.
//!
//! # Contract, as for shared memory
//!
//! Zenoh itself offers a reliable, ordered stream per session pair and, when its send queue
//! is full, either blocks (`CongestionControl::Block`) or drops silently
//! (`CongestionControl::Drop`). A silent drop would break the rule that every loss is
//! counted, and blocking inside Zenoh knows nothing of the receiver's buffer, so this module
//! adds **credit-based flow control** on top and uses `Block` underneath:
//!
//! - Every source has a random 64-bit port id and declares the liveliness token
//!   `terl/<run_id>/<topic>/rx/<id>`; every sink declares `…/tx/<id>`. Sinks count receivers
//!   (and sources count senders) from these tokens, so a receiver whose host disappears is
//!   no longer waited for once Zenoh's lease expires (10 s).
//! - A sink sends each message **to each receiver separately** (`…/to/<receiver id>`),
//!   prefixed by a 16-byte header (sender port id, link epoch; little-endian `u64`s) and
//!   followed by the message's bytes (`bytemuck::Pod`, exactly `size_of::<M>()` bytes).
//! - A sink may have at most the receiver's buffer size (`buffer_batches`,
//!   `buffer_episodes`, `buffer_selected`) of messages outstanding at each receiver. The
//!   source acknowledges every message it hands out (`…/ack/<sender id>`: receiver id,
//!   epoch, messages consumed in this epoch; 24 bytes) and each ack returns one credit.
//! - With no credit left the sink follows its [`OverflowPolicy`] exactly as over shared
//!   memory: `DropNewest` skips that receiver and returns [`SendOutcome::Full`]; `Block`
//!   waits for an ack up to the block timeout, then gives up with
//!   `TransportError::BlockTimeout`. Either way the message is counted in
//!   `dropped`/`dropped_items` and stamped on the next message ([`crate::flow`]).
//!
//! # Loss, ordering, back-pressure
//!
//! - **Ordering:** per sender and receiver, in send order (one reliable Zenoh stream).
//! - **Back-pressure:** the credits above; a receiver never holds more than its buffer
//!   from one sender, so Zenoh's own `Block` queue only waits for the network.
//! - **Loss:** given-up messages are counted by the sender and stamped. A message already
//!   handed to Zenoh is lost only when the TCP session between the two hosts closes (the
//!   link stayed down longer than the lease, or Zenoh's queue was blocked for 5 s); the
//!   receiver then counts it as a gap in the sender's sequence numbers
//!   ([`crate::LossTracker`]'s `missed`). A dropped sink lingers up to [`SINK_LINGER`]
//!   until its live receivers have consumed what it sent, so closing a process right after
//!   its last send loses nothing that was still in Zenoh's (or a router's) queues. The credits of such a link are reset when the
//!   receiver's token comes back (a new epoch). A message whose length is not the
//!   expected one is rejected and counted in the source's `rejected`.
//! - **Limits:** a new port counts the existing tokens of its kind first (a liveliness query
//!   to every reachable process) and is refused over the config's limit, like iceoryx2's
//!   table; two ports created at the same instant on different hosts can both get in.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, OnceLock};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use crate::channel::{Message, MessageSink, MessageSource, Transport};
use crate::config::{TransportConfig, ZenohConfig, ZenohMode};
use crate::error::TransportError;
use crate::flow::{OverflowPolicy, SendOutcome, StatsSnapshot, TransportStats};

mod claims;
mod router;
mod sink;
mod source;

pub use router::ZenohRouter;
pub use sink::ZenohSink;
pub use source::ZenohSource;
use source::{deliver, Incoming};

/// Bytes in front of every message: sender port id, link epoch.
pub const HEADER_BYTES: usize = 16;
/// Bytes of an acknowledgement: receiver port id, epoch, messages consumed in the epoch.
pub const ACK_BYTES: usize = 24;
/// How long a new port waits for the answers to its liveliness query (limits, receivers).
const QUERY_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a claimed actor id's token is given to reach the other processes before the
/// claimant checks for competing claims.
pub const CLAIM_SETTLE: Duration = Duration::from_millis(200);
/// How long a peer waits to meet the run's other peers before claiming an actor id.
pub const PEER_WAIT: Duration = Duration::from_secs(10);
/// Claims of one actor id before giving up while other processes claim it at the same time.
pub const CLAIM_ATTEMPTS: u32 = 5;
/// How long a sink waits for Zenoh to route to a newly seen receiver.
const MATCH_TIMEOUT: Duration = Duration::from_secs(5);
/// Slice of a blocked send between checks of the cancel flag.
const BLOCK_POLL: Duration = Duration::from_millis(5);
/// How long a dropped sink waits for its live receivers to take what it already handed to
/// Zenoh: closing the session at once would discard the frames still in Zenoh's queues
/// (and a router's), which the sink has already reported as delivered.
pub const SINK_LINGER: Duration = Duration::from_secs(2);

fn zenoh_err(
    operation: &'static str,
    key: &str,
    detail: impl core::fmt::Display,
) -> TransportError {
    TransportError::Zenoh {
        operation,
        key: key.to_owned(),
        detail: detail.to_string(),
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The last key component `<hex id>` of a liveliness token, or `None` for foreign keys.
fn token_id(key: &str) -> Option<u64> {
    u64::from_str_radix(key.rsplit('/').next()?, 16).ok()
}

/// Keys of the live tokens under `prefix/*`, asked of every process `session` reaches; at
/// most [`QUERY_TIMEOUT`].
fn live_tokens(session: &Session, prefix: &str) -> Result<Vec<String>, TransportError> {
    let query = format!("{prefix}/*");
    let replies = session
        .liveliness()
        .get(&query)
        .timeout(QUERY_TIMEOUT)
        .wait()
        .map_err(|e| zenoh_err("liveliness query", &query, e))?;
    let mut keys = vec![];
    while let Ok(reply) = replies.recv() {
        if let Ok(sample) = reply.result() {
            keys.push(sample.key_expr().as_str().to_owned());
        }
    }
    Ok(keys)
}

fn read_u64(bytes: &[u8], at: usize) -> Option<u64> {
    let b: [u8; 8] = bytes.get(at..at + 8)?.try_into().ok()?;
    Some(u64::from_le_bytes(b))
}

/// A process's Zenoh session for one run's streams.
#[derive(Clone)]
pub struct ZenohTransport {
    config: TransportConfig,
    session: Session,
    cancel: Arc<AtomicBool>,
    /// Peers this session had met when it first claimed an actor id (peer mode).
    peers_met: Arc<OnceLock<usize>>,
}

impl core::fmt::Debug for ZenohTransport {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ZenohTransport")
            .field("run_id", &self.config.run_id)
            .field("zid", &self.session.zid().to_string())
            .finish()
    }
}

/// Sets Zenoh's `transport/auth/usrpwd` from `secret`: the user and password this session
/// proves, and the dictionary it checks the sessions that connect to it against. Zenoh reads
/// the dictionary from a file while the session opens; on Linux that file is an anonymous
/// in-memory file (`memfd_create`, read through `/proc/self/fd`), so the secret never touches a
/// disk and nothing is left behind even when the process is killed. Elsewhere it is a private
/// temporary file. The returned handle keeps it readable; the caller drops it once the session
/// is open. Zenoh 1.10's handshake sends an HMAC of a nonce, never the password.
fn authenticate(
    zc: &mut zenoh::Config,
    secret: &crate::ZenohSecret,
) -> Result<Dictionary, TransportError> {
    let user = crate::ZenohSecret::USER;
    let dictionary = Dictionary::new(&format!("{user}:{}\n", secret.expose())).map_err(|e| {
        TransportError::Config(format!("cannot write the Zenoh authentication file: {e}"))
    })?;
    for (key, value) in [
        ("transport/auth/usrpwd/user", user),
        ("transport/auth/usrpwd/password", secret.expose()),
        (
            "transport/auth/usrpwd/dictionary_file",
            dictionary.path.as_str(),
        ),
    ] {
        // The error names the key only: the value may be the secret.
        zc.insert_json5(key, &serde_json::Value::from(value).to_string())
            .map_err(|_| TransportError::Config(format!("zenoh {key}: not accepted")))?;
    }
    Ok(dictionary)
}

/// The user/password dictionary as a file Zenoh can read by path.
struct Dictionary {
    #[cfg(target_os = "linux")]
    _file: std::fs::File,
    #[cfg(not(target_os = "linux"))]
    _file: tempfile::NamedTempFile,
    path: String,
}

impl Dictionary {
    #[cfg(target_os = "linux")]
    fn new(content: &str) -> std::io::Result<Self> {
        use std::io::Write as _;
        use std::os::fd::AsRawFd as _;
        let fd = nix::sys::memfd::memfd_create(
            c"terl-zenoh-auth",
            nix::sys::memfd::MFdFlags::MFD_CLOEXEC,
        )?;
        let mut file = std::fs::File::from(fd);
        file.write_all(content.as_bytes())?;
        let path = format!("/proc/self/fd/{}", file.as_raw_fd());
        Ok(Self { _file: file, path })
    }

    #[cfg(not(target_os = "linux"))]
    fn new(content: &str) -> std::io::Result<Self> {
        use std::io::Write as _;
        let mut file = tempfile::Builder::new().prefix("terl-zenoh-").tempfile()?;
        file.write_all(content.as_bytes())?;
        file.flush()?;
        let path = file.path().display().to_string();
        Ok(Self { _file: file, path })
    }
}

/// Opens a Zenoh session from `z` (mode, listen and connect endpoints, the secret, the TLS
/// files) after [`ZenohConfig::validate`] and [`ZenohConfig::check_locked`], with Zenoh's
/// access control carrying only the keys of run `run_id` (`terl/<run_id>/**`; every run's
/// `terl/**` for `None`, a router shared by runs). `role` only names the process in logs.
fn open_session(
    z: &ZenohConfig,
    run_id: Option<&str>,
    role: &str,
) -> Result<Session, TransportError> {
    z.validate()?;
    z.check_locked()?;
    let mut zc = zenoh::Config::default();
    let json = |v: &dyn erased::Json| v.json();
    let mode = match z.mode {
        ZenohMode::Peer => "peer",
        ZenohMode::Client => "client",
        ZenohMode::Router => "router",
    };
    let scope = match run_id {
        Some(run) => format!("terl/{run}/**"),
        None => "terl/**".to_string(),
    };
    for (key, value) in [
        ("mode", json(&mode)),
        ("scouting/multicast/enabled", json(&z.multicast_scouting)),
        ("connect/endpoints", json(&z.connect)),
        ("access_control", access_control(&scope).to_string()),
    ] {
        zc.insert_json5(key, &value)
            .map_err(|e| TransportError::Config(format!("zenoh {key} = {value}: {e}")))?;
    }
    let listen = crate::config::listen_endpoints(z);
    if !listen.is_empty() {
        let value = json(&listen);
        zc.insert_json5("listen/endpoints", &value)
            .map_err(|e| TransportError::Config(format!("zenoh listen = {value}: {e}")))?;
    }
    // Zenoh's QUIC transport (TLS 1.3; its settings are under `tls`) for `quic/` endpoints: the
    // files are read when a link opens, so they are checked here first, each named.
    let quic = z
        .listen
        .iter()
        .chain(&z.connect)
        .any(|e| e.starts_with("quic/"));
    for (key, setting, path) in [
        (
            "transport/link/tls/root_ca_certificate",
            "[cluster] tls_ca",
            &z.tls.ca,
        ),
        (
            "transport/link/tls/listen_certificate",
            "[cluster] tls_cert (terl zenoh-router --tls-cert)",
            &z.tls.cert,
        ),
        (
            "transport/link/tls/listen_private_key",
            "[cluster] tls_key (terl zenoh-router --tls-key)",
            &z.tls.key,
        ),
    ] {
        if let Some(path) = path {
            if quic {
                check_pem_file(setting, path)?;
            }
            let value = json(&path.display().to_string());
            zc.insert_json5(key, &value)
                .map_err(|e| TransportError::Config(format!("zenoh {key} = {value}: {e}")))?;
        }
    }
    // Zenoh's user/password authentication: every session both proves the secret (user,
    // password) and asks it of the sessions that connect to it (the dictionary, which Zenoh
    // reads from a file while the session opens; see `authenticate`).
    let dictionary = match &z.secret {
        Some(secret) => Some(authenticate(&mut zc, secret)?),
        None => None,
    };
    let session = zenoh::open(zc).wait().map_err(|e| {
        // A client opens only once a router (or a peer) let it in. Zenoh then says only
        // "Unable to connect to any of [...]" whether nothing listened, the token was refused
        // or the certificate was not trusted, so that error gets what to check; any other
        // (a listen endpoint in use, a bad file) is Zenoh's own.
        let text = e.to_string();
        if z.mode == ZenohMode::Client && text.contains("Unable to connect") {
            let text = text.trim_end().trim_end_matches(['!', '.']).trim_end();
            zenoh_err(
                "open session",
                &scope,
                format!("{text}; {}", refused_hint(z)),
            )
        } else {
            zenoh_err("open session", &scope, text)
        }
    })?;
    drop(dictionary);
    tracing::info!(
        role,
        zid = %session.zid(),
        mode,
        ?listen,
        connect = ?z.connect,
        authenticated = z.secret.is_some(),
        keys = scope,
        "zenoh session open"
    );
    Ok(session)
}

/// What a client whose session no endpoint accepted should check: something of the run listens
/// there, both sides hold the same token (the accepting side refuses a missing, extra or
/// different one without saying why) and, over `quic/`, the certificate is trusted for that host.
fn refused_hint(z: &ZenohConfig) -> String {
    let token = if z.secret.is_some() {
        "this process's token (TERL_TOKEN or [cluster] token_file) is the listener's: a listener \
         with another token, or with none, refuses it"
    } else {
        "this process has no token (TERL_TOKEN or [cluster] token_file): a listener that has one \
         refuses it"
    };
    let tls = if z.connect.iter().any(|e| e.starts_with("quic/")) {
        "; and over quic/, that [cluster] tls_ca is the CA that signed the listener's \
         certificate and that the endpoint's host is one the certificate names (`terl certs \
         --host`)"
    } else {
        ""
    };
    format!(
        "no endpoint of {:?} let this session in. Check that a router or a peer of the run \
         listens there; that {token}{tls}",
        z.connect
    )
}

/// The largest TLS file a session reads (a certificate chain or key is a few KiB).
const MAX_PEM_BYTES: u64 = 1 << 20;

/// Checks that `path` (the file of `setting`) is a readable regular file of at most
/// [`MAX_PEM_BYTES`] holding PEM (`-----BEGIN `): Zenoh reads it only when a link opens, and
/// then names neither the file nor the setting, blocks on a FIFO and reads `/dev/zero` without
/// end.
fn check_pem_file(setting: &str, path: &std::path::Path) -> Result<(), TransportError> {
    use std::io::Read as _;
    let bad = |why: String| TransportError::Config(format!("{setting}, {}: {why}", path.display()));
    let meta = std::fs::metadata(path).map_err(|e| bad(e.to_string()))?;
    if !meta.is_file() {
        return Err(bad("not a regular file".into()));
    }
    if meta.len() > MAX_PEM_BYTES {
        return Err(bad(format!("larger than {MAX_PEM_BYTES} bytes")));
    }
    let mut text = String::new();
    std::fs::File::open(path)
        .and_then(|f| f.take(MAX_PEM_BYTES).read_to_string(&mut text))
        .map_err(|e| bad(e.to_string()))?;
    if !text.contains("-----BEGIN ") {
        return Err(bad(
            "no PEM block in it (`terl certs` makes the run's files)".into(),
        ));
    }
    Ok(())
}

/// Zenoh's access control (`access_control` of its configuration) admitting, from and to
/// every other session, only messages on `scope` (declarations, puts, queries, replies and
/// liveliness of every kind) and denying everything else: a session of the run, even one
/// holding the token, cannot publish on, subscribe to or query another run's keys or any
/// other key through this process.
fn access_control(scope: &str) -> serde_json::Value {
    serde_json::json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": [{
            "id": "run-keys",
            "messages": [
                "put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"
            ],
            "flows": ["egress", "ingress"],
            "permission": "allow",
            "key_exprs": [scope],
        }],
        "subjects": [{ "id": "every-session" }],
        "policies": [{ "rules": ["run-keys"], "subjects": ["every-session"] }],
    })
}

impl ZenohTransport {
    /// Opens a Zenoh session from `config.zenoh` (mode, listen and connect endpoints). In
    /// peer mode the session opens even when no `connect` endpoint is reachable (after Zenoh's
    /// scouting delay, about 0.5 s), so a peer started while the others are unreachable sees
    /// none of them at first; in client mode it fails when none is reachable. `role` only
    /// names the process in logs.
    pub fn open(config: TransportConfig, role: &str) -> Result<Self, TransportError> {
        config.validate()?;
        let session = open_session(&config.zenoh, Some(&config.run_id), role)?;
        claims::serve(&session, &config.run_id)?;
        Ok(Self {
            config,
            session,
            cancel: Arc::default(),
            peers_met: Arc::default(),
        })
    }

    /// The configuration this transport was opened with.
    pub fn config(&self) -> &TransportConfig {
        &self.config
    }

    /// The underlying session (for tools that need Zenoh directly).
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Claims `actor_id` on this run for as long as the returned [`ZenohClaim`] lives: the
    /// liveliness token `terl/<run_id>/claims/actor-<id>/<claimed at>-<session id>` (the
    /// claim time in ms since the Unix epoch). A killed holder's
    /// token disappears with its session (at once on a closed connection, after Zenoh's 10 s
    /// lease when its host vanished). Errors with [`TransportError::IdInUse`] while a live
    /// process holds it.
    ///
    /// Every reachable process is asked for its own tokens of the id and for the claims it
    /// sees of its peers: actors on two hosts that reach each other only through the
    /// learner's session still see each other's claims, because every session answers
    /// `terl/<run_id>/claim-view/actor-<id>` with the claims it sees.
    ///
    /// Two holders can still meet after a partition heals (a learner restarted before the
    /// holder reconnected to it; a host back after its lease expired). The claim watches for
    /// that: its [`HeldClaim::superseded`](crate::HeldClaim::superseded) turns `Some` in the
    /// holder whose claim is the later one, which must stop.
    ///
    /// Two processes claiming the same id at the same instant never both get it: each
    /// declares its token first, lets it reach the others ([`CLAIM_SETTLE`]) and only then
    /// asks every reachable process for the id's claims; of two such claims at least one sees
    /// the other's token, and whoever sees another holder withdraws. A claimant that withdrew
    /// tries again after a random pause while no token of the id is seen, up to
    /// [`CLAIM_ATTEMPTS`] times.
    pub fn claim_actor_id(&self, actor_id: u16) -> Result<ZenohClaim, TransportError> {
        // A peer asks only the peers it is connected to: right after opening it may not have
        // met them yet, and would take an id a live actor holds. Waited for once per session
        // (an auto actor claims id after id).
        let must_meet = self.config.zenoh.mode == ZenohMode::Peer
            && !self.config.zenoh.connect.is_empty()
            && self.peers_met.get().is_none();
        if must_meet {
            let peers = self.settled_peers(PEER_WAIT);
            if peers > 0 {
                let _ = self.peers_met.set(peers);
            } else {
                return Err(TransportError::Timeout {
                    what: format!(
                        "a Zenoh peer at {:?}, to check that actor id {actor_id} is free (start \
                         the learner first; with a token, every process of the run needs the \
                         same TERL_TOKEN)",
                        self.config.zenoh.connect
                    ),
                    after: PEER_WAIT,
                });
            }
        }
        let prefix = claims::claim_prefix(&self.config.run_id, actor_id);
        let key = claims::claim_key(&prefix, &self.session.zid().to_string());
        let in_use = || TransportError::IdInUse {
            what: format!("actor id {actor_id}"),
            run_id: self.config.run_id.clone(),
            service: prefix.clone(),
        };
        for attempt in 0..CLAIM_ATTEMPTS {
            if self.other_holders(actor_id, &key)? {
                return Err(in_use());
            }
            let token = self.declare_token(&key)?;
            std::thread::sleep(CLAIM_SETTLE);
            if !self.other_holders(actor_id, &key)? {
                let watch = claims::Watch::start(
                    self.session.clone(),
                    self.config.run_id.clone(),
                    actor_id,
                    key.clone(),
                );
                return Ok(ZenohClaim {
                    key,
                    watch,
                    _token: token,
                });
            }
            drop(token);
            let pause = rand::random::<u64>() % (50 * (u64::from(attempt) + 1));
            std::thread::sleep(CLAIM_SETTLE + Duration::from_millis(pause));
        }
        Err(in_use())
    }

    /// Waits until this session is connected to at least one peer and the number of peers
    /// has not changed for 300 ms (gossip has brought the rest), at most `limit`; returns the
    /// number of peers.
    fn settled_peers(&self, limit: Duration) -> usize {
        let start = Instant::now();
        let (mut count, mut since) = (usize::MAX, Instant::now());
        loop {
            let now = self.session.info().peers_zid().wait().count();
            if now != count {
                (count, since) = (now, Instant::now());
            }
            let settled = count > 0 && since.elapsed() >= Duration::from_millis(300);
            if settled || start.elapsed() >= limit {
                return count;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Whether a live claim of `actor_id` (a token under `prefix/*`) other than `mine`
    /// exists: asked of every reachable process, for its own tokens and for the claims it
    /// sees (a holder this session is not connected to; see [`claims`]).
    fn other_holders(&self, actor_id: u16, mine: &str) -> Result<bool, TransportError> {
        Ok(
            claims::holders(&self.session, &self.config.run_id, actor_id)?
                .iter()
                .any(|key| key != mine),
        )
    }

    /// Declares the liveliness token `key`, alive until dropped.
    fn declare_token(&self, key: &str) -> Result<LivelinessToken, TransportError> {
        self.session
            .liveliness()
            .declare_token(key)
            .wait()
            .map_err(|e| zenoh_err("declare token", key, e))
    }

    fn key(&self, topic: crate::Topic, rest: &str) -> String {
        format!("{}/{rest}", self.config.service_name(topic))
    }

    /// Ids of the live tokens under `prefix/*`, asked of every reachable process.
    fn query_tokens(&self, prefix: &str) -> Result<Vec<u64>, TransportError> {
        let mut ids = vec![];
        for id in live_tokens(&self.session, prefix)?
            .iter()
            .filter_map(|k| token_id(k))
        {
            if !ids.contains(&id) {
                ids.push(id);
            }
        }
        Ok(ids)
    }

    /// Declares the liveliness token of a new port of kind `kind` (`tx`/`rx`) after checking
    /// that fewer than `max` exist.
    fn claim_port(
        &self,
        topic: crate::Topic,
        kind: &'static str,
        max: usize,
    ) -> Result<(u64, LivelinessToken), TransportError> {
        let prefix = self.key(topic, kind);
        let existing = self.query_tokens(&prefix)?;
        if existing.len() >= max {
            return Err(zenoh_err(
                if kind == "tx" {
                    "publisher creation"
                } else {
                    "subscriber creation"
                },
                &prefix,
                format!(
                    "{} {kind} ports already live, the run allows {max}",
                    existing.len()
                ),
            ));
        }
        let id = loop {
            let id: u64 = rand::random();
            if !existing.contains(&id) {
                break id;
            }
        };
        let key = format!("{prefix}/{id:016x}");
        Ok((id, self.declare_token(&key)?))
    }

    /// Follows the live tokens under `prefix/*` into `peers` (id → generation) and wakes
    /// `wake` on every change. Fills `peers` with the tokens alive now before returning.
    fn track_tokens(
        &self,
        prefix: &str,
        shared: &Arc<Shared>,
    ) -> Result<Subscriber<()>, TransportError> {
        let key = format!("{prefix}/*");
        let s = Arc::clone(shared);
        let subscriber = self
            .session
            .liveliness()
            .declare_subscriber(&key)
            .history(true)
            .callback(move |sample| {
                let Some(id) = token_id(sample.key_expr().as_str()) else {
                    return;
                };
                let mut state = lock(&s.state);
                match sample.kind() {
                    SampleKind::Put => state.add_peer(id),
                    SampleKind::Delete => {
                        state.peers.remove(&id);
                    }
                }
                drop(state);
                s.wake.notify_all();
            })
            .wait()
            .map_err(|e| zenoh_err("liveliness subscriber", &key, e))?;
        let now = self.query_tokens(prefix)?;
        let mut state = lock(&shared.state);
        for id in now {
            state.add_peer(id);
        }
        Ok(subscriber)
    }

    /// A sink on `M`'s topic with the config's overflow policy.
    pub fn zenoh_sink<M: Message>(&self) -> Result<ZenohSink<M>, TransportError> {
        self.zenoh_sink_with(self.config.overflow)
    }

    /// A sink on `M`'s topic with an explicit overflow policy. Errors when the run's
    /// publisher limit for the topic is reached.
    pub fn zenoh_sink_with<M: Message>(
        &self,
        policy: OverflowPolicy,
    ) -> Result<ZenohSink<M>, TransportError> {
        let topic = M::TOPIC;
        let limits = self.config.limits(topic);
        let (id, token) = self.claim_port(topic, "tx", limits.max_publishers)?;
        let shared = Arc::new(Shared::default());
        let ack_key = self.key(topic, &format!("ack/{id:016x}"));
        let s = Arc::clone(&shared);
        let acks = self
            .session
            .declare_subscriber(&ack_key)
            .callback(move |sample| {
                let bytes = sample.payload().to_bytes();
                let parsed = (bytes.len() == ACK_BYTES)
                    .then(|| {
                        Some((
                            read_u64(&bytes, 0)?,
                            read_u64(&bytes, 8)?,
                            read_u64(&bytes, 16)?,
                        ))
                    })
                    .flatten();
                let Some((receiver, epoch, consumed)) = parsed else {
                    s.rejected.fetch_add(1, Ordering::Relaxed);
                    return;
                };
                let mut state = lock(&s.state);
                let entry = state.acks.entry(receiver).or_insert((epoch, 0));
                if entry.0 != epoch {
                    *entry = (epoch, consumed);
                } else {
                    entry.1 = entry.1.max(consumed);
                }
                drop(state);
                s.wake.notify_all();
            })
            .wait()
            .map_err(|e| zenoh_err("ack subscriber", &ack_key, e))?;
        let receivers = self.track_tokens(&self.key(topic, "rx"), &shared)?;
        Ok(ZenohSink {
            label: self.config.service_name(topic),
            id,
            session: self.session.clone(),
            policy,
            buffer: limits.subscriber_buffer as u64,
            block_timeout: self.config.block_timeout,
            cancel: Arc::clone(&self.cancel),
            shared,
            links: HashMap::new(),
            frame: vec![0; HEADER_BYTES + core::mem::size_of::<M>()],
            stats: Arc::default(),
            _token: token,
            _acks: acks,
            _receivers: receivers,
            _topic: std::marker::PhantomData,
        })
    }

    /// A source on `M`'s topic. Errors when the run's subscriber limit for the topic is
    /// reached (one learner, one selector).
    pub fn zenoh_source<M: Message>(&self) -> Result<ZenohSource<M>, TransportError> {
        let topic = M::TOPIC;
        let limits = self.config.limits(topic);
        let (id, token) = self.claim_port(topic, "rx", limits.max_subscribers)?;
        let shared = Arc::new(Shared::default());
        // Credits bound what is queued to `buffer` per sender; the channel bound is a
        // backstop against a sender that ignores them.
        let capacity = limits.subscriber_buffer * limits.max_publishers;
        let (tx, rx) = crossbeam_channel::bounded::<Incoming<M>>(capacity);
        let data_key = self.key(topic, &format!("to/{id:016x}"));
        let s = Arc::clone(&shared);
        let data = self
            .session
            .declare_subscriber(&data_key)
            .callback(move |sample| deliver(&s, &tx, &sample.payload().to_bytes()))
            .wait()
            .map_err(|e| zenoh_err("data subscriber", &data_key, e))?;
        let senders = self.track_tokens(&self.key(topic, "tx"), &shared)?;
        Ok(ZenohSource {
            label: self.config.service_name(topic),
            id,
            prefix: self.config.service_name(topic),
            session: self.session.clone(),
            rx,
            shared,
            consumed: HashMap::new(),
            ack_publishers: HashMap::new(),
            stats: Arc::default(),
            _token: token,
            _data: data,
            _senders: senders,
        })
    }
}

/// Waits until Zenoh routes `publisher`'s puts to a matching subscriber (a declaration travels
/// separately from the liveliness token that announced it), polling every millisecond, at most
/// [`MATCH_TIMEOUT`] or until `give_up` says so. `Ok(false)`: not routed.
fn wait_until_routed(
    publisher: &Publisher<'static>,
    label: &str,
    mut give_up: impl FnMut() -> bool,
) -> Result<bool, TransportError> {
    let start = Instant::now();
    loop {
        let status = publisher
            .matching_status()
            .wait()
            .map_err(|e| zenoh_err("matching status", label, e))?;
        if status.matching() {
            return Ok(true);
        }
        if give_up() || start.elapsed() >= MATCH_TIMEOUT {
            return Ok(false);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}

impl Transport for ZenohTransport {
    fn sink<M: Message>(&self) -> Result<Box<dyn MessageSink<M>>, TransportError> {
        Ok(Box::new(self.zenoh_sink::<M>()?))
    }

    fn source<M: Message>(&self) -> Result<Box<dyn MessageSource<M>>, TransportError> {
        Ok(Box::new(self.zenoh_source::<M>()?))
    }

    fn cancel_blocked_sends(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// An actor id held by this process over Zenoh (see [`ZenohTransport::claim_actor_id`]);
/// released when dropped.
pub struct ZenohClaim {
    key: String,
    /// Stopped (its thread joined) when the claim is dropped.
    watch: claims::Watch,
    _token: LivelinessToken,
}

impl crate::channel::HeldClaim for ZenohClaim {
    /// Checked every 2 s in the background: an earlier claim of the same id, seen once two
    /// parts of the run meet again.
    fn superseded(&self) -> Option<String> {
        self.watch.superseded_by().map(|earlier| {
            format!(
                "this process claimed it as {} but an earlier claim, {earlier}, is live too \
                 (two parts of the run met again: a learner restarted before the earlier \
                 holder reconnected, or a host came back after its lease expired)",
                self.key
            )
        })
    }
}

impl core::fmt::Debug for ZenohClaim {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ZenohClaim")
            .field("key", &self.key)
            .finish()
    }
}

/// State a port shares with its Zenoh callbacks.
#[derive(Debug, Default)]
struct Shared {
    state: Mutex<PortState>,
    wake: Condvar,
    /// Frames or acks of the wrong size, or frames beyond the queue's bound.
    rejected: AtomicU64,
}

#[derive(Debug, Default)]
struct PortState {
    /// Live peer ports (receivers of a sink, senders of a source) → generation, new each
    /// time a token appears.
    peers: HashMap<u64, u64>,
    next_generation: u64,
    /// Sink: receiver id → (epoch, messages it consumed in that epoch).
    acks: HashMap<u64, (u64, u64)>,
}

impl PortState {
    /// Messages `receiver` acknowledged as consumed in link epoch `epoch` (0 for another epoch).
    fn consumed(&self, receiver: u64, epoch: u64) -> u64 {
        match self.acks.get(&receiver) {
            Some(&(e, consumed)) if e == epoch => consumed,
            _ => 0,
        }
    }

    fn add_peer(&mut self, id: u64) {
        if let std::collections::hash_map::Entry::Vacant(e) = self.peers.entry(id) {
            self.next_generation += 1;
            e.insert(self.next_generation);
        }
    }
}

/// JSON5 values of the config entries.
mod erased {
    pub trait Json {
        fn json(&self) -> String;
    }
    impl<T: serde::Serialize> Json for T {
        fn json(&self) -> String {
            serde_json::to_string(self).expect("plain values serialise")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A client that no endpoint lets in is told what to check (Zenoh says only "Unable to
    /// connect"); one that fails for another reason (its own listen endpoint taken) is not.
    #[test]
    fn only_a_client_nobody_let_in_gets_the_refusal_hint() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let free_port = free.local_addr().unwrap().port();
        drop(free);
        let client = |listen: Vec<String>| ZenohConfig {
            mode: ZenohMode::Client,
            connect: vec![format!("tcp/127.0.0.1:{free_port}")],
            listen,
            ..Default::default()
        };
        let Err(nobody) = open_session(&client(vec![]), Some("hint-test"), "test") else {
            panic!("a client opened with nothing listening")
        };
        let nobody = nobody.to_string();
        assert!(
            nobody.contains("Unable to connect")
                && nobody.contains("no endpoint of")
                && nobody.contains("this process has no token")
                && !nobody.contains("tls_ca"),
            "{nobody}"
        );
        let port = taken.local_addr().unwrap().port();
        let Err(in_use) = open_session(
            &client(vec![format!("tcp/127.0.0.1:{port}")]),
            Some("hint-test"),
            "test",
        ) else {
            panic!("a client listened on a taken port")
        };
        let in_use = in_use.to_string();
        assert!(!in_use.contains("no endpoint of"), "{in_use}");
    }

    /// A TLS file that Zenoh would fail on later, hang on or read without end is refused when
    /// the session opens, naming the setting and the file.
    #[test]
    fn tls_files_are_checked_before_the_session_opens() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("ca.pem");
        std::fs::write(
            &good,
            "-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n",
        )
        .unwrap();
        check_pem_file("[cluster] tls_ca", &good).unwrap();
        let garbage = dir.path().join("garbage.pem");
        std::fs::write(&garbage, "not a certificate").unwrap();
        let fifo = dir.path().join("fifo");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
        let big = dir.path().join("big.pem");
        std::fs::File::create(&big)
            .unwrap()
            .set_len(MAX_PEM_BYTES + 1)
            .unwrap();
        for (path, why) in [
            (dir.path().join("missing.pem"), "No such file"),
            (dir.path().to_path_buf(), "not a regular file"),
            (fifo, "not a regular file"),
            (std::path::PathBuf::from("/dev/zero"), "not a regular file"),
            (big, "larger than"),
            (garbage, "no PEM block"),
        ] {
            let e = check_pem_file("[cluster] tls_ca", &path)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("tls_ca") && e.contains(&path.display().to_string()) && e.contains(why),
                "{e}"
            );
        }
        // The session refuses to open with such a file, naming it.
        let e = ZenohTransport::open(
            TransportConfig {
                zenoh: ZenohConfig {
                    connect: vec!["quic/127.0.0.1:9".into()],
                    tls: crate::ZenohTls {
                        ca: Some(dir.path().join("missing.pem")),
                        ..crate::ZenohTls::default()
                    },
                    ..ZenohConfig::default()
                },
                ..TransportConfig::new("pem-check", 1)
            },
            "actor",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("missing.pem") && e.contains("tls_ca"), "{e}");
    }

    /// The access control of a run's session, against a session that holds the run's secret
    /// but runs no access control of its own (as a modified process would): of the keys that
    /// session publishes, only the run's reach the run's process, and of the keys the run's
    /// process publishes, only the run's reach that session.
    #[test]
    fn a_run_s_session_carries_only_the_run_s_keys() {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let endpoint = format!("tcp/127.0.0.1:{port}");
        let secret = crate::ZenohSecret::new("acl-test-secret-0123456789").unwrap();
        let run = format!("acl-{}", std::process::id());
        let learner = ZenohTransport::open(
            TransportConfig {
                zenoh: ZenohConfig {
                    listen: vec![endpoint.clone()],
                    secret: Some(secret.clone()),
                    ..ZenohConfig::default()
                },
                transport: crate::TransportKind::Zenoh,
                ..TransportConfig::new(&run, 1)
            },
            "learner",
        )
        .unwrap();
        let mut zc = zenoh::Config::default();
        zc.insert_json5("mode", "\"peer\"").unwrap();
        zc.insert_json5("scouting/multicast/enabled", "false")
            .unwrap();
        zc.insert_json5(
            "connect/endpoints",
            &serde_json::json!([endpoint]).to_string(),
        )
        .unwrap();
        let dictionary = authenticate(&mut zc, &secret).unwrap();
        let outsider = zenoh::open(zc).wait().unwrap();
        drop(dictionary);

        let keys = [
            format!("terl/{run}/transitions/to/1"),
            format!("terl/{run}-other/transitions/to/1"),
            "terl/another-run/x".to_string(),
            "elsewhere/x".to_string(),
        ];
        // Every key subscribed on both sides; what each side receives.
        let got: [Arc<Mutex<Vec<String>>>; 2] = Default::default();
        let mut subscribers = vec![];
        for (session, got) in [(learner.session(), &got[0]), (&outsider, &got[1])] {
            for key in &keys {
                let got = Arc::clone(got);
                subscribers.push(
                    session
                        .declare_subscriber(key.as_str())
                        .callback(move |s| lock(&got).push(s.key_expr().to_string()))
                        .wait()
                        .unwrap(),
                );
            }
        }
        // Both ways, every key, until the run's key has arrived both ways (routes settle).
        let start = Instant::now();
        let mut round = 0u8;
        loop {
            for session in [learner.session(), &outsider] {
                for key in &keys {
                    session.put(key.as_str(), vec![round]).wait().unwrap();
                }
            }
            std::thread::sleep(Duration::from_millis(100));
            round += 1;
            let arrived = got.iter().all(|g| lock(g).iter().any(|k| k == &keys[0]));
            if arrived && round >= 5 {
                break;
            }
            assert!(
                start.elapsed() < Duration::from_secs(20),
                "the run's own key never crossed: {got:?}"
            );
        }
        for (side, got) in ["the run's process", "the outsider"].iter().zip(&got) {
            let got = lock(got);
            // Each side hears its own `round` puts of every key (a local subscriber); more
            // than that came from the other session.
            let heard = |key: &String| got.iter().filter(|k| *k == key).count();
            assert!(heard(&keys[0]) > usize::from(round), "{side}: {got:?}");
            for key in &keys[1..] {
                assert_eq!(
                    heard(key),
                    usize::from(round),
                    "{side} received {key} from the other session"
                );
            }
        }
    }
}
