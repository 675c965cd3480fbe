//! Publishing weights: the policy every `[cluster] publish_every_updates` updates, with
//! `algorithm = "terl"` the critics every `critic_publish_every_updates` and the planner when
//! it has a new version. A version is the learner's update count at publication, so a
//! transition's staleness is "updates behind" directly.

use terl_rl::Sac;
use terl_wire::{WeightHub, Weights, WeightsKind};

use crate::planner::PlannerTrainer;

/// The SAC networks of `kind` (critics, else the policy) as a weight message.
fn sac_weights(sac: &Sac<f32>, kind: WeightsKind, version: u64) -> anyhow::Result<Weights> {
    let tensors = match kind {
        WeightsKind::Critic => sac.critic_tensors(),
        _ => sac.policy_tensors(),
    };
    crate::to_weights(kind, version, sac.updates(), tensors)
}

/// When and what the learner publishes, and the versions published so far.
#[derive(Debug)]
pub(crate) struct Publisher {
    every: u64,
    critic_every: u64,
    /// Critics are published too (`algorithm = "terl"`: the selector's PTR scoring).
    critics: bool,
    pub(crate) policy_version: u64,
    pub(crate) critic_version: u64,
}

impl Publisher {
    /// Publishes the policy every `every` updates and, with `critics`, the critics every
    /// `critic_every` updates (at a policy publication).
    pub(crate) fn new(every: u64, critic_every: u64, critics: bool) -> Self {
        Self {
            every,
            critic_every,
            critics,
            policy_version: 0,
            critic_version: 0,
        }
    }

    /// Publishes everything at once at the current update count (a resumed learner: actors
    /// and the selector get the restored networks without waiting for the next period).
    ///
    /// # Errors
    /// A message over the hub's size limit, or tensors that do not convert.
    pub(crate) fn publish_all(
        &mut self,
        hub: &WeightHub,
        sac: &Sac<f32>,
        planner: Option<&mut PlannerTrainer>,
    ) -> anyhow::Result<()> {
        let version = sac.updates();
        hub.publish(&sac_weights(sac, WeightsKind::Policy, version)?)?;
        self.policy_version = version;
        if self.critics {
            hub.publish(&sac_weights(sac, WeightsKind::Critic, version)?)?;
            self.critic_version = version;
        }
        if let Some(p) = planner {
            if let Some(w) = p.weights_to_publish()? {
                hub.publish(&w)?;
            }
        }
        Ok(())
    }

    /// Publishes what is due at `sac`'s update count; true if the policy was published.
    ///
    /// # Errors
    /// As [`Publisher::publish_all`].
    pub(crate) fn publish_due(
        &mut self,
        hub: &WeightHub,
        sac: &Sac<f32>,
        planner: Option<&mut PlannerTrainer>,
    ) -> anyhow::Result<bool> {
        let version = sac.updates();
        if version < self.policy_version + self.every {
            return Ok(false);
        }
        hub.publish(&sac_weights(sac, WeightsKind::Policy, version)?)?;
        self.policy_version = version;
        if self.critics && version >= self.critic_version + self.critic_every {
            hub.publish(&sac_weights(sac, WeightsKind::Critic, version)?)?;
            self.critic_version = version;
        }
        if let Some(p) = planner {
            if let Some(w) = p.weights_to_publish()? {
                hub.publish(&w)?;
            }
        }
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use terl_rl::replay::MultiTaskReplay;
    use terl_rl::Batch;
    use terl_transport::{ACTION_DIM, OBS_DIM};

    /// Over 23 real updates with K = 5 and critics every 10: the policy goes out at updates
    /// 5, 10, 15, 20 (versions increasing, each the update count), the critics at 10 and 20,
    /// and nothing in between.
    #[test]
    fn the_policy_goes_out_every_k_updates_with_increasing_versions() {
        let config = terl_rl::SacConfig {
            obs_dim: OBS_DIM,
            act_dim: ACTION_DIM,
            num_tasks: 1,
            policy_hidden: vec![8],
            critic_hidden: vec![8],
            batch_size: 8,
            ..terl_rl::SacConfig::default()
        };
        let mut sac = Sac::<f32>::new(config).unwrap();
        let mut replay = MultiTaskReplay::new(1, 64, OBS_DIM, ACTION_DIM);
        for k in 0..64 {
            let x = (k as f32 * 0.37).sin();
            replay.push(
                0,
                &[x; OBS_DIM],
                &[0.1, -0.2, x, 0.0],
                x,
                &[x * 0.5; OBS_DIM],
                false,
            );
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut batch = Batch::with_capacity(8, OBS_DIM, ACTION_DIM);
        let hub = WeightHub::new();
        let mut publisher = Publisher::new(5, 10, true);
        let (mut policy_at, mut critic_at) = (Vec::new(), Vec::new());
        for _ in 0..23 {
            replay.sample_into(8, &mut rng, &mut batch);
            sac.update(&batch).unwrap();
            let critic_before = publisher.critic_version;
            if publisher.publish_due(&hub, &sac, None).unwrap() {
                assert_eq!(hub.latest_version(WeightsKind::Policy), sac.updates());
                policy_at.push(publisher.policy_version);
            }
            if publisher.critic_version != critic_before {
                assert_eq!(hub.latest_version(WeightsKind::Critic), sac.updates());
                critic_at.push(publisher.critic_version);
            }
        }
        assert_eq!(sac.updates(), 23);
        assert_eq!(policy_at, [5, 10, 15, 20]);
        assert_eq!(critic_at, [10, 20]);
        assert_eq!(hub.latest_version(WeightsKind::Policy), 20);

        // Without critics (MTSAC) only the policy goes out.
        let hub = WeightHub::new();
        let mut mtsac = Publisher::new(5, 10, false);
        assert!(mtsac.publish_due(&hub, &sac, None).unwrap());
        assert_eq!(hub.latest_version(WeightsKind::Policy), 23);
        assert_eq!(hub.latest_version(WeightsKind::Critic), 0);
        assert!(!mtsac.publish_due(&hub, &sac, None).unwrap());
    }
}
