//! The learner's latest weights, fanned out to every `WatchWeights` stream.
//!
//! The learner calls [`WeightHub::publish`] once per new version; the hub encodes it once
//! (little-endian bytes and CRC-32, into reference-counted buffers) and every subscriber stream
//! sends that same encoded message. Delivery semantics: **latest wins**. The hub keeps only the
//! newest version of each kind (a `tokio::sync::watch` channel), so a subscriber that reads slower
//! than the learner publishes skips the versions it missed and receives the newest one next.
//! Versions of a kind therefore arrive in strictly increasing order but possibly with gaps — what
//! an actor wants (acting with an old policy has no value once a newer one exists), and the
//! learner never waits for, nor buffers for, a slow actor.

use std::sync::Arc;

use tokio::sync::watch;

use crate::pb;
use crate::weights::{Weights, WeightsKind};
use crate::DEFAULT_MAX_MESSAGE_BYTES;

/// Why a version was not published.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PublishError {
    /// Versions of a kind must strictly increase; the hub keeps the one it has.
    #[error("{kind} weights version {version} is not newer than the published version {latest}")]
    NotNewer {
        /// Kind of the rejected weights.
        kind: WeightsKind,
        /// Their version.
        version: u64,
        /// The version of that kind already published.
        latest: u64,
    },
    /// The encoded `WeightsUpdate` is larger than the hub's gRPC message limit
    /// ([`WeightHub::max_message_bytes`]); no subscriber could decode it.
    #[error(
        "{kind} weights version {version} encode to {bytes} bytes, over the {limit}-byte gRPC \
         message limit; raise ServeOptions::max_message_bytes (and the clients' limit) or send \
         fewer parameters"
    )]
    TooLarge {
        /// Kind of the rejected weights.
        kind: WeightsKind,
        /// Their version.
        version: u64,
        /// Size of the encoded message, bytes.
        bytes: usize,
        /// The message limit, bytes.
        limit: usize,
    },
}

/// The newest encoded version of each kind.
#[derive(Debug, Clone, Default)]
pub(crate) struct Latest {
    by_kind: [Option<Arc<pb::WeightsUpdate>>; 3],
}

impl Latest {
    pub(crate) fn get(&self, kind: WeightsKind) -> Option<&Arc<pb::WeightsUpdate>> {
        self.by_kind[kind.index()].as_ref()
    }
}

/// Publishes weight versions to all subscribers; cheap to clone (all clones share one channel).
#[derive(Debug, Clone)]
pub struct WeightHub {
    sender: Arc<watch::Sender<Latest>>,
    max_message_bytes: usize,
}

impl Default for WeightHub {
    fn default() -> Self {
        Self::new()
    }
}

impl WeightHub {
    /// A hub that refuses versions larger than [`DEFAULT_MAX_MESSAGE_BYTES`] encoded.
    pub fn new() -> Self {
        Self::with_max_message_bytes(DEFAULT_MAX_MESSAGE_BYTES)
    }

    /// A hub whose size check matches a server started with a different message limit.
    pub fn with_max_message_bytes(max_message_bytes: usize) -> Self {
        let (sender, _) = watch::channel(Latest::default());
        Self {
            sender: Arc::new(sender),
            max_message_bytes,
        }
    }

    /// Makes `weights` the newest version of its kind and wakes every subscriber. The version
    /// must be greater than the previously published one of the same kind, and the encoded
    /// message must fit the message limit (checked here so that an oversized version fails at
    /// the learner, loudly, rather than as a stream error at every actor). Never blocks on
    /// subscribers.
    pub fn publish(&self, weights: &Weights) -> Result<(), PublishError> {
        let (kind, version) = (weights.kind(), weights.version());
        let latest = self.latest_version(kind);
        if version <= latest {
            return Err(PublishError::NotNewer {
                kind,
                version,
                latest,
            });
        }
        let encoded = pb::WeightsUpdate::from(weights);
        let bytes = prost::Message::encoded_len(&encoded);
        if bytes > self.max_message_bytes {
            return Err(PublishError::TooLarge {
                kind,
                version,
                bytes,
                limit: self.max_message_bytes,
            });
        }
        let encoded = Arc::new(encoded);
        let mut result = Ok(());
        self.sender.send_modify(|state| {
            // Re-checked under the channel lock: two publishers racing keep the newer one.
            let slot = &mut state.by_kind[kind.index()];
            match slot.as_ref().map(|w| w.version) {
                Some(current) if current >= version => {
                    result = Err(PublishError::NotNewer {
                        kind,
                        version,
                        latest: current,
                    })
                }
                _ => *slot = Some(encoded),
            }
        });
        if result.is_ok() {
            tracing::debug!(%kind, version, bytes, subscribers = self.subscriber_count(), "published weights");
        }
        result
    }

    /// Newest published version of `kind` (0 = none yet).
    pub fn latest_version(&self, kind: WeightsKind) -> u64 {
        self.sender.borrow().get(kind).map_or(0, |w| w.version)
    }

    /// Number of open subscriptions (`WatchWeights` streams served right now).
    pub fn subscriber_count(&self) -> usize {
        self.sender.receiver_count()
    }

    /// Largest encoded `WeightsUpdate` the hub publishes, bytes ([`DEFAULT_MAX_MESSAGE_BYTES`]
    /// unless built with [`Self::with_max_message_bytes`]); should match the server's
    /// [`crate::ServeOptions::max_message_bytes`].
    pub fn max_message_bytes(&self) -> usize {
        self.max_message_bytes
    }

    pub(crate) fn subscribe(&self) -> watch::Receiver<Latest> {
        self.sender.subscribe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::weights::Tensor;

    fn weights(kind: WeightsKind, version: u64, n: usize) -> Weights {
        let t = Tensor::new("w", vec![n], vec![version as f32; n]).unwrap();
        Weights::new(kind, version, version * 10, vec![t]).unwrap()
    }

    #[test]
    fn versions_must_increase_per_kind() {
        let hub = WeightHub::new();
        hub.publish(&weights(WeightsKind::Policy, 2, 4)).unwrap();
        hub.publish(&weights(WeightsKind::Planner, 1, 4)).unwrap();
        assert_eq!(
            hub.publish(&weights(WeightsKind::Policy, 2, 4)),
            Err(PublishError::NotNewer {
                kind: WeightsKind::Policy,
                version: 2,
                latest: 2
            })
        );
        assert_eq!(hub.latest_version(WeightsKind::Policy), 2);
        assert_eq!(hub.latest_version(WeightsKind::Planner), 1);
        assert_eq!(hub.latest_version(WeightsKind::Critic), 0);
    }

    #[test]
    fn oversized_versions_are_refused_at_publish() {
        let hub = WeightHub::with_max_message_bytes(1000);
        let err = hub
            .publish(&weights(WeightsKind::Policy, 1, 1000))
            .unwrap_err();
        assert!(
            matches!(err, PublishError::TooLarge { limit: 1000, .. }),
            "{err}"
        );
        assert_eq!(hub.latest_version(WeightsKind::Policy), 0);
    }
}
