//! Zenoh's own router for clusters whose processes run in `client` mode.

use super::*;

/// A Zenoh router for a cluster whose processes run in `client` mode (`terl zenoh-router`,
/// the Kubernetes manifests' `terl-zenoh`): Zenoh's own router, with the session settings of
/// [`ZenohConfig`] (mode forced to `router`; multicast scouting as configured). Routes the keys
/// of one run (`terl/<run_id>/**`) or, without a run id, of every run (`terl/**`), and nothing
/// else (Zenoh's access control). It keeps no state of its own, so restarting it only
/// interrupts the streams (losses counted by the senders and receivers as for a link outage);
/// with a run id it also answers for the actor-id claims it sees, as every session of the run
/// does. Stops when dropped.
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
    /// Opens the router session for run `run_id` (every run for `None`), listening on
    /// `config.listen`.
    ///
    /// # Errors
    /// [`TransportError::Config`] for a malformed endpoint or run id, for multicast scouting,
    /// for an endpoint beyond loopback that is not `quic/` or has no `config.secret`, and for a
    /// `quic/` endpoint without its files ([`ZenohConfig::check_locked`]);
    /// [`TransportError::Zenoh`] when Zenoh cannot open the session (e.g. the port is taken).
    pub fn open(config: &ZenohConfig, run_id: Option<&str>) -> Result<Self, TransportError> {
        let config = ZenohConfig {
            mode: ZenohMode::Router,
            ..config.clone()
        };
        if let Some(run) = run_id {
            TransportConfig::new(run, 1).validate()?;
        }
        let session = open_session(&config, run_id, "router")?;
        if let Some(run) = run_id {
            claims::serve(&session, run)?;
        }
        Ok(Self { session })
    }

    /// The underlying session (e.g. to read its id or peers).
    pub fn session(&self) -> &Session {
        &self.session
    }
}
