//! Zenoh's own router for clusters whose processes run in `client` mode.

use super::*;

/// A Zenoh router for a cluster whose processes run in `client` mode (`terl zenoh-router`,
/// the Kubernetes manifests' `terl-zenoh`): Zenoh's own router, with the session settings of
/// [`ZenohConfig`] (mode forced to `router`; multicast scouting as configured). Routes every
/// run's keys; it keeps no state of its own, so restarting it only interrupts the streams
/// (losses counted by the senders and receivers as for a link outage). Stops when dropped.
pub struct ZenohRouter {
    pub(super) session: Session,
}

impl core::fmt::Debug for ZenohRouter {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("ZenohRouter")
            .field("zid", &self.session.zid())
            .finish()
    }
}

impl ZenohRouter {
    /// Opens the router session, listening on `config.listen`.
    ///
    /// # Errors
    /// [`TransportError::Config`] for a malformed endpoint, for multicast scouting, and for an
    /// endpoint beyond loopback without `config.secret`; [`TransportError::Zenoh`] when Zenoh
    /// cannot open the session (e.g. the port is taken).
    pub fn open(config: &ZenohConfig) -> Result<Self, TransportError> {
        let config = ZenohConfig {
            mode: ZenohMode::Router,
            ..config.clone()
        };
        let transport = ZenohTransport::open(
            TransportConfig {
                zenoh: config,
                transport: crate::TransportKind::Zenoh,
                ..TransportConfig::new("router", 1)
            },
            "router",
        )?;
        Ok(Self {
            session: transport.session,
        })
    }

    /// The underlying session (e.g. to read its id or peers).
    pub fn session(&self) -> &Session {
        &self.session
    }
}
