//! The actor-id claims a session sees, served to claimants that cannot reach their holders.
//!
//! A liveliness query is answered only by the sessions the asker is connected to, and a peer
//! forwards no other peer's tokens (Zenoh brokers between peers only in a router). Actors on
//! different hosts connect to the learner's endpoint but, listening on loopback by default,
//! not to each other: an actor asking for the tokens of its id would miss a holder on another
//! host and take the id too. So every session keeps the claims it sees (a liveliness
//! subscriber on `terl/<run_id>/claims/**`, history included) and answers the query
//! `terl/<run_id>/claim-view/actor-<id>` with the keys it sees for that id, one per line.
//! The learner, which every actor reaches, sees every live claim.

use std::collections::{BTreeSet, HashSet};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use zenoh::query::ConsolidationMode;
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use super::{live_tokens, lock, zenoh_err, QUERY_TIMEOUT};
use crate::error::TransportError;

/// How often a holder checks that no earlier claim of its id has appeared.
pub const WATCH_EVERY: Duration = Duration::from_secs(2);
/// Lines read of one claim-view reply (a run has at most 65536 actor ids, and one id has one
/// holder but for a moment).
const MAX_VIEW_LINES: usize = 1024;

/// The key under which a claim of `actor_id` is declared (`/<claimed at>-<session id>`
/// follows).
pub(super) fn claim_prefix(run_id: &str, actor_id: u16) -> String {
    format!("terl/{run_id}/claims/actor-{actor_id}")
}

/// A claim's key: `<prefix>/<ms since the Unix epoch>-<session id>`.
pub(super) fn claim_key(prefix: &str, zid: &str) -> String {
    let ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    format!("{prefix}/{ms}-{zid}")
}

/// The order of claims: earlier time first, then the session id; a key without a readable
/// time sorts first (the earliest claim).
fn claim_order(key: &str) -> (u128, &str) {
    let last = key.rsplit('/').next().unwrap_or(key);
    match last.split_once('-') {
        Some((ms, zid)) => ms.parse().map_or((0, last), |ms| (ms, zid)),
        None => (0, last),
    }
}

fn view_key(run_id: &str, actor_id: u16) -> String {
    format!("terl/{run_id}/claim-view/actor-{actor_id}")
}

/// Keeps the claims of run `run_id` that `session` sees and answers claim-view queries from
/// them, for as long as the session lives.
///
/// # Errors
/// [`TransportError::Zenoh`] when the subscriber or the queryable cannot be declared.
pub(super) fn serve(session: &Session, run_id: &str) -> Result<(), TransportError> {
    let seen: Arc<Mutex<BTreeSet<String>>> = Arc::default();
    let claims = format!("terl/{run_id}/claims/**");
    let keep = Arc::clone(&seen);
    session
        .liveliness()
        .declare_subscriber(&claims)
        .history(true)
        .callback(move |sample| {
            let key = sample.key_expr().as_str().to_owned();
            match sample.kind() {
                SampleKind::Put => lock(&keep).insert(key),
                SampleKind::Delete => lock(&keep).remove(&key),
            };
        })
        .background()
        .wait()
        .map_err(|e| zenoh_err("liveliness subscriber", &claims, e))?;
    let views = format!("terl/{run_id}/claim-view/*");
    let run = run_id.to_owned();
    session
        .declare_queryable(&views)
        .callback(move |query| {
            let Some(id) = query
                .key_expr()
                .as_str()
                .rsplit('/')
                .next()
                .and_then(|last| last.strip_prefix("actor-"))
                .and_then(|id| id.parse::<u16>().ok())
            else {
                return;
            };
            let prefix = format!("{}/", claim_prefix(&run, id));
            let keys: Vec<String> = lock(&seen)
                .iter()
                .filter(|k| k.starts_with(&prefix))
                .cloned()
                .collect();
            let key = query.key_expr().clone();
            if let Err(e) = query.reply(key, keys.join("\n")).wait() {
                tracing::debug!(error = %e, "claim view reply not sent");
            }
        })
        .background()
        .wait()
        .map_err(|e| zenoh_err("queryable", &views, e))?;
    Ok(())
}

/// The claims of `actor_id` that the sessions reachable from `session` see (their own and
/// those of their peers); at most [`QUERY_TIMEOUT`].
///
/// # Errors
/// [`TransportError::Zenoh`] when the query cannot be sent.
fn ask(session: &Session, run_id: &str, actor_id: u16) -> Result<HashSet<String>, TransportError> {
    let key = view_key(run_id, actor_id);
    let prefix = format!("{}/", claim_prefix(run_id, actor_id));
    let replies = session
        .get(&key)
        .consolidation(ConsolidationMode::None)
        .timeout(QUERY_TIMEOUT)
        .wait()
        .map_err(|e| zenoh_err("query", &key, e))?;
    let mut keys: HashSet<String> = HashSet::new();
    while let Ok(reply) = replies.recv() {
        let Ok(sample) = reply.result() else { continue };
        let bytes = sample.payload().to_bytes();
        for line in String::from_utf8_lossy(&bytes).lines().take(MAX_VIEW_LINES) {
            // `<prefix>/<one key component>`, nothing else.
            let is_claim = line.strip_prefix(&prefix).is_some_and(|rest| {
                !rest.is_empty() && rest.len() <= 64 && !rest.contains(['/', '*', '$', '?', '#'])
            });
            if is_claim {
                keys.insert(line.to_owned());
            }
        }
    }
    Ok(keys)
}

/// Every live claim of `actor_id` that the sessions reachable from `session` hold or see,
/// without duplicates.
pub(super) fn holders(
    session: &Session,
    run_id: &str,
    actor_id: u16,
) -> Result<Vec<String>, TransportError> {
    let mut keys = ask(session, run_id, actor_id)?;
    keys.extend(live_tokens(session, &claim_prefix(run_id, actor_id))?);
    Ok(keys.into_iter().collect())
}

/// Watches a held claim: every [`WATCH_EVERY`] it asks for the id's holders and, once one
/// whose claim is earlier than this one is seen, records it and stops watching. Stopped
/// (and its thread joined) when dropped.
pub(super) struct Watch {
    stop: Arc<AtomicBool>,
    superseded: Arc<Mutex<Option<String>>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Watch {
    pub(super) fn start(session: Session, run_id: String, actor_id: u16, mine: String) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let superseded: Arc<Mutex<Option<String>>> = Arc::default();
        let (halt, found) = (Arc::clone(&stop), Arc::clone(&superseded));
        let thread = std::thread::Builder::new()
            .name(format!("claim-watch-{actor_id}"))
            .spawn(move || {
                let order = claim_order(&mine);
                loop {
                    let since = Instant::now();
                    while since.elapsed() < WATCH_EVERY {
                        if halt.load(Ordering::Relaxed) {
                            return;
                        }
                        std::thread::sleep(Duration::from_millis(50));
                    }
                    // A failed query (the session closing) is tried again next time.
                    let Ok(keys) = holders(&session, &run_id, actor_id) else {
                        continue;
                    };
                    if let Some(earlier) = keys
                        .into_iter()
                        .filter(|k| *k != mine)
                        .min_by(|a, b| claim_order(a).cmp(&claim_order(b)))
                        .filter(|k| claim_order(k) < order)
                    {
                        *lock(&found) = Some(earlier);
                        return;
                    }
                }
            })
            .ok();
        Self {
            stop,
            superseded,
            thread,
        }
    }

    /// The earlier claim seen, if any.
    pub(super) fn superseded_by(&self) -> Option<String> {
        lock(&self.superseded).clone()
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn claims_order_by_time_then_session() {
        let p = claim_prefix("run", 3);
        assert_eq!(p, "terl/run/claims/actor-3");
        let key = claim_key(&p, "abc");
        let (ms, zid) = claim_order(&key);
        assert_eq!(zid, "abc");
        assert!(ms > 1_700_000_000_000, "{key}");
        assert!(claim_order(&format!("{p}/5-b")) < claim_order(&format!("{p}/6-a")));
        assert!(claim_order(&format!("{p}/5-a")) < claim_order(&format!("{p}/5-b")));
        // No readable time: the earliest.
        assert!(claim_order(&format!("{p}/zid")) < claim_order(&format!("{p}/1-a")));
    }
}
