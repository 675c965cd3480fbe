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

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

use zenoh::query::ConsolidationMode;
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use super::{lock, zenoh_err, QUERY_TIMEOUT};
use crate::error::TransportError;

/// The key under which a claim of `actor_id` is declared (`/<session id>` follows).
pub(super) fn claim_prefix(run_id: &str, actor_id: u16) -> String {
    format!("terl/{run_id}/claims/actor-{actor_id}")
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
/// those of their peers), without duplicates; at most [`QUERY_TIMEOUT`].
///
/// # Errors
/// [`TransportError::Zenoh`] when the query cannot be sent.
pub(super) fn ask(
    session: &Session,
    run_id: &str,
    actor_id: u16,
) -> Result<Vec<String>, TransportError> {
    let key = view_key(run_id, actor_id);
    let prefix = format!("{}/", claim_prefix(run_id, actor_id));
    let replies = session
        .get(&key)
        .consolidation(ConsolidationMode::None)
        .timeout(QUERY_TIMEOUT)
        .wait()
        .map_err(|e| zenoh_err("query", &key, e))?;
    let mut keys: Vec<String> = vec![];
    while let Ok(reply) = replies.recv() {
        let Ok(sample) = reply.result() else { continue };
        let bytes = sample.payload().to_bytes();
        for line in String::from_utf8_lossy(&bytes).lines() {
            if line.starts_with(&prefix) && !keys.iter().any(|k| k == line) {
                keys.push(line.to_owned());
            }
        }
    }
    Ok(keys)
}
