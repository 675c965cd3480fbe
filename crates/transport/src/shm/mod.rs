//! The iceoryx2 implementation of the transport seam: zero-copy shared memory between
//! processes on one host.
//!
//! One [`ShmTransport`] per process (it owns the iceoryx2 node); sinks are publishers and
//! sources are subscribers of `terl/<run_id>/<topic>`. Every service is created with
//! safe overflow **off**, so a full subscriber is never silently overwritten: the
//! publisher's back-pressure handler either retries (policy `Block`) or discards for that
//! subscriber (policy `DropNewest`), and counts the event either way.
//!
//! Ports use iceoryx2's thread-safe service variant, so a sink or source can be moved to
//! the thread that uses it; the mutex this adds is uncontended and paid once per batch.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::port::notifier::{Notifier, NotifierCreateError};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::port::{BackpressureAction, BackpressureInfo, SendError};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use serde::{Deserialize, Serialize};

use crate::channel::{Message, MessageSink, MessageSource, Transport};
use crate::config::{TransportConfig, PUBLISHER_MAX_LOANED, SUBSCRIBER_MAX_BORROWED};
use crate::error::TransportError;
use crate::flow::{OverflowPolicy, SendOutcome, StatsSnapshot, TransportStats};
use space::{check_free_space, SHM_PATH};

mod sink;
mod source;
pub mod space;

pub use sink::ShmSink;
pub use source::ShmSource;

/// The iceoryx2 service flavour: inter-process, ports usable from any thread.
pub type ShmService = iceoryx2::service::ipc_threadsafe::Service;

/// What the start-up stale-resource cleanup did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StaleCleanup {
    /// Dead nodes (crashed or killed processes) whose resources were removed.
    pub cleaned: u64,
    /// Dead nodes that could not be cleaned (permissions, another cleaner busy).
    pub failed: u64,
}

/// A process's handle on a run's shared-memory streams.
pub struct ShmTransport {
    config: TransportConfig,
    node: Arc<Node<ShmService>>,
    cleanup: StaleCleanup,
    cancel: Arc<AtomicBool>,
}

impl core::fmt::Debug for ShmTransport {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ShmTransport")
            .field("run_id", &self.config.run_id)
            .field("node", &self.node.name().as_str())
            .field("cleanup", &self.cleanup)
            .finish()
    }
}

fn ipc_err(
    operation: &'static str,
    service: &str,
    detail: impl core::fmt::Debug,
) -> TransportError {
    TransportError::Ipc {
        operation,
        service: service.to_owned(),
        detail: format!("{detail:?}"),
    }
}

impl ShmTransport {
    /// Creates this process's node `terl/<run_id>/<role>`, removes stale resources of dead
    /// nodes (a crashed process must not wedge the next run), and checks `/dev/shm`.
    ///
    /// iceoryx2's own SIGINT/SIGTERM handling is disabled: the service owns its signals.
    pub fn open(config: TransportConfig, role: &str) -> Result<Self, TransportError> {
        config.validate()?;
        let node_label = format!("terl/{}/{role}", config.run_id);
        let node_name =
            NodeName::new(&node_label).map_err(|e| ipc_err("node name", &node_label, e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ShmService>()
            .map_err(|e| ipc_err("node creation", &node_label, e))?;
        let state = node.try_cleanup_dead_nodes();
        let cleanup = StaleCleanup {
            cleaned: state.cleanups,
            failed: state.failed_cleanups,
        };
        if cleanup.cleaned > 0 || cleanup.failed > 0 {
            tracing::warn!(
                cleaned = cleanup.cleaned,
                failed = cleanup.failed,
                "removed stale shared-memory resources of dead iceoryx2 nodes"
            );
        }
        Ok(Self {
            config,
            node: Arc::new(node),
            cleanup,
            cancel: Arc::default(),
        })
    }

    /// Checks that `/dev/shm` can hold the whole run (every actor, learner and selector);
    /// for launchers, before starting any process.
    pub fn check_shm_for_run(config: &TransportConfig) -> Result<u64, TransportError> {
        check_free_space(Path::new(SHM_PATH), config.required_shm_bytes())
    }

    /// The configuration this transport was opened with.
    pub fn config(&self) -> &TransportConfig {
        &self.config
    }

    /// The stale-resource cleanup done when this transport was opened.
    pub fn stale_cleanup(&self) -> StaleCleanup {
        self.cleanup
    }

    /// Runs the dead-node cleanup again (e.g. periodically in a long-lived learner).
    pub fn cleanup_dead_nodes(&self) -> StaleCleanup {
        let state = self.node.try_cleanup_dead_nodes();
        StaleCleanup {
            cleaned: state.cleanups,
            failed: state.failed_cleanups,
        }
    }

    /// Claims `actor_id` on this run for as long as the returned [`SenderClaim`] lives, so two
    /// actor processes never stream under one id (their sequence numbers and loss stamps
    /// would mix, and each would take the other's share of the tasks twice).
    ///
    /// The claim is the only notifier port of the iceoryx2 event service
    /// `terl/<run_id>/claims/actor-<id>` — the same mechanism that keeps a run to one learner
    /// (its transition subscriber is the only one the service allows). A killed holder's port
    /// is removed by the dead-node cleanup of the next [`ShmTransport::open`], so a restarted
    /// actor gets its id back. Errors with [`TransportError::IdInUse`] while another live
    /// process holds the id.
    pub fn claim_actor_id(&self, actor_id: u16) -> Result<SenderClaim, TransportError> {
        let label = format!("terl/{}/claims/actor-{actor_id}", self.config.run_id);
        let name: ServiceName = label
            .as_str()
            .try_into()
            .map_err(|e| ipc_err("service name", &label, e))?;
        let in_use = || TransportError::IdInUse {
            what: format!("actor id {actor_id}"),
            run_id: self.config.run_id.clone(),
            service: label.clone(),
        };
        let factory = match self
            .node
            .service_builder(&name)
            .event()
            .max_notifiers(1)
            .max_listeners(1)
            .max_nodes(CLAIM_MAX_NODES)
            .open_or_create()
        {
            Ok(f) => f,
            Err(EventOpenOrCreateError::EventOpenError(
                EventOpenError::ExceedsMaxNumberOfNodes,
            )) => return Err(in_use()),
            Err(e) => return Err(ipc_err("open_or_create claim", &label, e)),
        };
        match factory.notifier_builder().create() {
            Ok(notifier) => Ok(SenderClaim {
                label,
                _notifier: notifier,
                _factory: factory,
                _node: Arc::clone(&self.node),
            }),
            Err(NotifierCreateError::ExceedsMaxSupportedNotifiers) => Err(in_use()),
            Err(e) => Err(ipc_err("claim", &label, e)),
        }
    }

    /// Sleeps for `cycle`; the one place a main loop waits (`while t.wait(cycle)`).
    pub fn wait(&self, cycle: Duration) -> bool {
        self.node.wait(cycle).is_ok()
    }

    fn service<M: Message>(
        &self,
    ) -> Result<(String, PubSubFactory<ShmService, M, ()>), TransportError> {
        let label = self.config.service_name(M::TOPIC);
        let name: ServiceName = label
            .as_str()
            .try_into()
            .map_err(|e| ipc_err("service name", &label, e))?;
        let limits = self.config.limits(M::TOPIC);
        let factory = self
            .node
            .service_builder(&name)
            .publish_subscribe::<M>()
            .max_publishers(limits.max_publishers)
            .max_subscribers(limits.max_subscribers)
            .max_nodes(limits.max_nodes)
            .subscriber_max_buffer_size(limits.subscriber_buffer)
            .subscriber_max_borrowed_samples(SUBSCRIBER_MAX_BORROWED)
            .history_size(0)
            .enable_safe_overflow(false)
            .open_or_create()
            .map_err(|e| ipc_err("open_or_create service", &label, e))?;
        Ok((label, factory))
    }

    /// A publisher on `M`'s topic with the config's overflow policy.
    pub fn shm_sink<M: Message>(&self) -> Result<ShmSink<M>, TransportError> {
        self.shm_sink_with(self.config.overflow)
    }

    /// A publisher on `M`'s topic with an explicit overflow policy.
    pub fn shm_sink_with<M: Message>(
        &self,
        policy: OverflowPolicy,
    ) -> Result<ShmSink<M>, TransportError> {
        if self.config.check_shm {
            check_free_space(
                Path::new(SHM_PATH),
                self.config.publisher_segment_bytes::<M>(),
            )?;
        }
        let (label, factory) = self.service::<M>()?;
        let full_hits = Arc::new(AtomicU64::new(0));
        let handler_hits = Arc::clone(&full_hits);
        let timeout = self.config.block_timeout;
        let cancel = Arc::clone(&self.cancel);
        let handler_cancel = Arc::clone(&self.cancel);
        let handler = move |info: &BackpressureInfo| {
            if info.retries == 0 {
                handler_hits.fetch_add(1, Ordering::Relaxed);
            }
            match policy {
                OverflowPolicy::DropNewest => BackpressureAction::DiscardData,
                OverflowPolicy::Block
                    if info.elapsed_time >= timeout || handler_cancel.load(Ordering::Relaxed) =>
                {
                    BackpressureAction::DiscardDataAndFail
                }
                OverflowPolicy::Block => BackpressureAction::Retry,
            }
        };
        let strategy = match policy {
            OverflowPolicy::Block => BackpressureStrategy::RetryUntilDelivered,
            OverflowPolicy::DropNewest => BackpressureStrategy::DiscardData,
        };
        let publisher = factory
            .publisher_builder()
            .max_loaned_samples(PUBLISHER_MAX_LOANED)
            .backpressure_strategy(strategy)
            .set_backpressure_handler(handler)
            .create()
            .map_err(|e| ipc_err("publisher creation", &label, e))?;
        Ok(ShmSink {
            label,
            factory,
            publisher,
            policy,
            block_timeout: timeout,
            full_hits,
            cancel,
            stats: Arc::default(),
            _node: Arc::clone(&self.node),
        })
    }

    /// A subscriber on `M`'s topic.
    pub fn shm_source<M: Message>(&self) -> Result<ShmSource<M>, TransportError> {
        let (label, factory) = self.service::<M>()?;
        let subscriber = factory
            .subscriber_builder()
            .buffer_size(self.config.limits(M::TOPIC).subscriber_buffer)
            .create()
            .map_err(|e| ipc_err("subscriber creation", &label, e))?;
        // Attach to the publishers that exist now; later ones attach on receive.
        subscriber
            .update_connections()
            .map_err(|e| ipc_err("subscriber connect", &label, e))?;
        Ok(ShmSource {
            label,
            factory,
            subscriber,
            stats: Arc::default(),
            _node: Arc::clone(&self.node),
        })
    }
}

impl Transport for ShmTransport {
    fn sink<M: Message>(&self) -> Result<Box<dyn MessageSink<M>>, TransportError> {
        Ok(Box::new(self.shm_sink::<M>()?))
    }

    fn source<M: Message>(&self) -> Result<Box<dyn MessageSource<M>>, TransportError> {
        Ok(Box::new(self.shm_source::<M>()?))
    }

    fn cancel_blocked_sends(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }
}

/// Nodes that may open a claim service at once: the holder plus processes trying (and
/// failing) to claim the same id.
const CLAIM_MAX_NODES: usize = 16;

/// An actor id held by this process (see [`ShmTransport::claim_actor_id`]); released when
/// dropped, or by the dead-node cleanup when the process is killed.
pub struct SenderClaim {
    label: String,
    _notifier: Notifier<ShmService>,
    _factory: EventFactory<ShmService>,
    _node: Arc<Node<ShmService>>,
}

impl crate::channel::HeldClaim for SenderClaim {}

impl core::fmt::Debug for SenderClaim {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SenderClaim")
            .field("service", &self.label)
            .finish()
    }
}
