//! PTR scoring of finished episodes (`algorithm = "terl"`, paper Sec. IV.A).
//!
//! Per episode of a task whose success gate is open (rolling training success ≥ threshold):
//! `V(s_0..s_T)` and `H(s_0..s_{T−1})` from the newest policy and critics on the weight stream
//! (`H` is the entropy of the executed, tanh-squashed policy), GAE with bootstrap from `V(s_T)`
//! (Meta-World episodes end by the time limit), priority `P_t = α·mean(GAE) + (1 − α)·H(s_t)` per
//! transition. Scored episodes enter their task's pool ([`PtrPool`], `[ptr] pool_trajectories`);
//! a full pool is ranked across its trajectories, and its top fraction leaves in batches of 512
//! drawn from the ranking. Pools are per task: advantages of different tasks come from
//! different reward scales and value estimates, and one global ranking would fill the TEP
//! dataset with whichever task has the largest. Episodes of closed gates, or before both weight
//! kinds arrived, are counted and not scored; a pool that is not full when the selector stops
//! is not selected.

use terl_rl::ptr::{trajectory_priorities, PtrConfig, PtrPool, SuccessGate, TrajectoryEnd};
use terl_rl::value::ValueEstimator;
use terl_rl::SacConfig;
#[cfg(test)]
use terl_transport::Message;
use terl_transport::{EpisodeSummary, SelectedSample, OBS_DIM};
use terl_wire::PriorityStats;

/// Globally unique trajectory id: actor in the top 16 bits, the actor's episode counter below.
pub fn trajectory_id(actor_id: u16, episode_index: u64) -> u64 {
    (u64::from(actor_id) << 48) | (episode_index & ((1 << 48) - 1))
}

/// Running statistics of the priorities computed so far.
#[derive(Debug, Clone, Default)]
struct Priorities {
    scored: u64,
    sum: f64,
    /// Sums of the GAE and entropy parts ([`PtrConfig::priority`]'s two terms).
    gae_part_sum: f64,
    entropy_part_sum: f64,
    min: f64,
    max: f64,
    threshold: f64,
}

impl Priorities {
    fn record(&mut self, p: f64) {
        if self.scored == 0 {
            (self.min, self.max) = (p, p);
        }
        self.scored += 1;
        self.sum += p;
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }
}

/// Gate, value estimates, batching and statistics.
#[derive(Debug)]
pub struct Scorer {
    cfg: PtrConfig,
    gate: SuccessGate,
    estimator: ValueEstimator,
    /// One pool of scored trajectories per task.
    pools: Vec<PtrPool<SelectedSample>>,
    obs: Vec<f32>,
    values: Vec<f64>,
    entropies: Vec<f64>,
    rewards: Vec<f64>,
    priorities: Priorities,
    /// Episodes of open gates that arrived before the weights did.
    pub unscored_no_weights: u64,
    /// Episodes whose scores were not finite (a diverged critic); dropped.
    pub unscored_non_finite: u64,
    /// Transitions selected so far, over all tasks (what the pools released for the TEP buffer).
    pub selected: u64,
}

impl Scorer {
    /// A scorer with PTR settings `cfg` for `sac.num_tasks` tasks: empty pools, no weights
    /// loaded yet.
    pub fn new(cfg: PtrConfig, sac: &SacConfig) -> Self {
        Self {
            gate: SuccessGate::new(&cfg, sac.num_tasks),
            estimator: ValueEstimator::new(sac, 256),
            pools: (0..sac.num_tasks).map(|_| PtrPool::new(&cfg)).collect(),
            cfg,
            obs: Vec::new(),
            values: Vec::new(),
            entropies: Vec::new(),
            rewards: Vec::new(),
            priorities: Priorities::default(),
            unscored_no_weights: 0,
            unscored_non_finite: 0,
            selected: 0,
        }
    }

    /// The value estimator, to load the policy and critic weights from the weight stream into.
    pub fn estimator_mut(&mut self) -> &mut ValueEstimator {
        &mut self.estimator
    }

    /// Version of the critic weights loaded (0: none yet).
    pub fn critic_version(&self) -> u64 {
        self.estimator.critic_version()
    }

    /// Whether `task`'s success gate is open (its episodes are scored and selected).
    pub fn gate_open(&self, task: usize) -> bool {
        self.gate.is_open(task)
    }

    /// Records an episode of an earlier process of this run (read back from its episode log on
    /// resume) in the success gate only: gates open and latch as they did, nothing is scored.
    pub fn replay_episode(&mut self, task: usize, success: bool) {
        self.gate.record(task, success);
    }

    /// Records `episode` in the gate and, if its task's gate is open and weights are loaded,
    /// scores it and adds it to its task's pool. When that fills the pool, returns the pool's
    /// selection (highest priority first: the batches of 512 in order), otherwise nothing.
    pub fn on_episode(&mut self, e: &EpisodeSummary) -> Vec<(f64, SelectedSample)> {
        let task = usize::from(e.task);
        if !self.gate.record(task, e.succeeded()) {
            return Vec::new();
        }
        if !self.estimator.is_ready() {
            self.unscored_no_weights += 1;
            return Vec::new();
        }
        let steps = e.steps();
        let n = steps.len();
        if n == 0 {
            return Vec::new();
        }
        self.obs.clear();
        for s in steps {
            self.obs.extend_from_slice(&s.obs);
        }
        self.obs.extend_from_slice(&e.final_obs);
        self.values.resize(n + 1, 0.0);
        self.entropies.resize(n + 1, 0.0);
        if let Err(err) =
            self.estimator
                .evaluate(&self.obs, task, &mut self.values, &mut self.entropies)
        {
            tracing::warn!("episode not scored: {err}");
            return Vec::new();
        }
        self.rewards.clear();
        self.rewards
            .extend(steps.iter().map(|s| f64::from(s.reward)));
        let end = TrajectoryEnd::Truncated {
            last_value: self.values[n],
        };
        let (prios, mean_gae) = trajectory_priorities(
            &self.cfg,
            &self.rewards,
            &self.values[..n],
            end,
            &self.entropies[..n],
        );
        if prios.iter().any(|p| !p.is_finite()) {
            self.unscored_non_finite += 1;
            return Vec::new();
        }
        let id = trajectory_id(e.actor_id, e.episode_index);
        for &p in &prios {
            self.priorities.record(p);
        }
        let gae_part = self.cfg.gae_weight * mean_gae;
        self.priorities.gae_part_sum += gae_part * n as f64;
        self.priorities.entropy_part_sum += self.entropies[..n]
            .iter()
            .map(|&h| (1.0 - self.cfg.gae_weight) * h)
            .sum::<f64>();
        let samples = prios.iter().enumerate().map(|(t, &p)| {
            let next_obs: [f32; OBS_DIM] = if t + 1 < n {
                steps[t + 1].obs
            } else {
                e.final_obs
            };
            let sample = SelectedSample {
                trajectory_id: id,
                obs: steps[t].obs,
                next_obs,
                action: steps[t].action,
                reward: steps[t].reward,
                priority: p as f32,
                step_index: t as u16,
                task: e.task,
                variation: e
                    .variation()
                    .and_then(|v| u16::try_from(v).ok())
                    .unwrap_or(u16::MAX),
                success: u8::from(e.first_success_index().is_some_and(|f| t >= f)),
                reserved: 0,
            };
            (p, sample)
        });
        let out: Vec<(f64, SelectedSample)> = self.pools[task]
            .push_trajectory(samples)
            .into_iter()
            .flatten()
            .collect();
        if let Some(&(last, _)) = out.last() {
            self.priorities.threshold = last;
        }
        self.selected += out.len() as u64;
        out
    }

    /// Priority statistics for status.
    pub fn priority_stats(&self) -> PriorityStats {
        let p = &self.priorities;
        let mean_of = |sum: f64| {
            if p.scored > 0 {
                sum / p.scored as f64
            } else {
                0.0
            }
        };
        PriorityStats {
            scored: p.scored,
            mean: if p.scored > 0 {
                p.sum / p.scored as f64
            } else {
                0.0
            },
            min: p.min,
            max: p.max,
            selection_threshold: p.threshold,
            gae_part_mean: mean_of(p.gae_part_sum),
            entropy_part_mean: mean_of(p.entropy_part_sum),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use terl_rl::Sac;
    use terl_transport::TrajectoryStep;

    fn sac_config() -> SacConfig {
        SacConfig {
            obs_dim: OBS_DIM,
            act_dim: 4,
            num_tasks: 2,
            policy_hidden: vec![8],
            critic_hidden: vec![8],
            batch_size: 4,
            ..SacConfig::default()
        }
    }

    fn episode(task: u16, index: u64, success: bool, len: usize) -> Box<EpisodeSummary> {
        episode_with(task, index, success, len, |t| {
            if t % 7 == 0 {
                1.0
            } else {
                0.0
            }
        })
    }

    fn episode_with(
        task: u16,
        index: u64,
        success: bool,
        len: usize,
        reward: impl Fn(usize) -> f32,
    ) -> Box<EpisodeSummary> {
        let mut e = EpisodeSummary::empty();
        e.task = task;
        e.actor_id = 3;
        e.episode_index = index;
        e.success = u8::from(success);
        for t in 0..len {
            let mut s = TrajectoryStep::ZERO;
            s.obs[0] = t as f32 * 0.01;
            s.reward = reward(t);
            assert!(e.push_step(s));
        }
        e.length = len as u32;
        e
    }

    fn loaded(cfg: PtrConfig) -> Scorer {
        let sc = sac_config();
        let sac: Sac<f32> = Sac::new(sc.clone()).unwrap();
        let mut s = Scorer::new(cfg, &sc);
        s.estimator_mut()
            .set_policy(&sac.policy_params_f32(), 1)
            .unwrap();
        let critics: Vec<f32> = sac
            .critic_tensors()
            .iter()
            .flat_map(|t| t.values::<f32>().unwrap())
            .collect();
        s.estimator_mut().set_critics(&critics, 1).unwrap();
        s
    }

    #[test]
    fn nothing_is_scored_until_the_gate_opens() {
        let cfg = PtrConfig {
            success_threshold: 0.5,
            success_window: 4,
            batch_size: 16,
            top_fraction: 0.25,
            ..PtrConfig::default()
        };
        let mut s = loaded(cfg);
        // 1 success of 4: 25 % < 50 %.
        for (k, ok) in [false, false, false, true].into_iter().enumerate() {
            assert!(s.on_episode(&episode(0, k as u64, ok, 10)).is_empty());
        }
        assert_eq!(s.priority_stats().scored, 0);
        // Task 1 opening does not open task 0.
        for k in 0..4 {
            s.on_episode(&episode(1, 10 + k, true, 10));
        }
        assert!(s.gate_open(1) && !s.gate_open(0));
        // The gate opens with the 4th episode (min_episodes = window = 4), which is scored.
        assert_eq!(s.priority_stats().scored, 10);
        s.on_episode(&episode(1, 20, false, 10));
        assert_eq!(s.priority_stats().scored, 20, "the gate latches open");
    }

    #[test]
    fn selections_are_the_top_fraction_of_a_pool_and_keep_their_origin() {
        let cfg = PtrConfig {
            success_threshold: 0.0,
            min_episodes: Some(1),
            batch_size: 16,
            pool_trajectories: 1,
            top_fraction: 0.25,
            ..PtrConfig::default()
        };
        let mut s = loaded(cfg);
        let sel = s.on_episode(&episode(1, 5, true, 20));
        assert_eq!(sel.len(), 5, "a pool of one 20-step trajectory → top 5");
        assert!(sel.windows(2).all(|w| w[0].0 >= w[1].0));
        for (p, x) in &sel {
            assert_eq!(x.trajectory_id, trajectory_id(3, 5));
            assert_eq!(x.task, 1);
            assert_eq!(x.priority, *p as f32);
            let t = usize::from(x.step_index);
            assert_eq!(x.obs[0], t as f32 * 0.01);
            let next = if t + 1 < 20 {
                (t + 1) as f32 * 0.01
            } else {
                0.0
            };
            assert_eq!(x.next_obs[0], next);
        }
        let stats = s.priority_stats();
        assert_eq!(stats.scored, 20);
        assert!(stats.min <= stats.mean && stats.mean <= stats.max);
        assert_eq!(stats.selection_threshold, sel.last().unwrap().0);
        // The two parts add up to the mean priority (a second path: the recorded priorities).
        assert!(
            (stats.gae_part_mean + stats.entropy_part_mean - stats.mean).abs()
                <= 1e-9 * stats.mean.abs().max(1.0),
            "{stats:?}"
        );
        assert!(stats.entropy_part_mean != 0.0);
    }

    /// A selected sample carries its episode's goal variation and whether the task reported
    /// success after its step (from the episode's first success on), as the actor recorded them.
    #[test]
    fn selections_carry_the_variation_and_the_success_from_the_first_success_on() {
        let cfg = PtrConfig {
            success_threshold: 0.0,
            min_episodes: Some(1),
            batch_size: 16,
            pool_trajectories: 1,
            top_fraction: 1.0,
            ..PtrConfig::default()
        };
        let mut s = loaded(cfg);
        let mut e = episode(0, 1, true, 10);
        e.variation = 7;
        e.first_success = 4 + 1;
        let sel = s.on_episode(&e);
        assert_eq!(sel.len(), 10);
        for (_, x) in &sel {
            assert_eq!(x.variation(), Some(7));
            assert_eq!(x.succeeded(), x.step_index >= 4, "step {}", x.step_index);
        }
        // An episode without the records: unknown variation, no success flag.
        let sel = s.on_episode(&episode(0, 2, true, 10));
        assert!(sel
            .iter()
            .all(|(_, x)| x.variation().is_none() && !x.succeeded()));
    }

    /// Trajectories are ranked against each other: of two episodes over the same states, the
    /// one with the higher advantage (rewards) is selected first, although it arrived second
    /// and the first alone fills a batch; pools are per task.
    #[test]
    fn the_higher_advantage_trajectory_is_selected_first() {
        let cfg = PtrConfig {
            success_threshold: 0.0,
            min_episodes: Some(1),
            batch_size: 16,
            pool_trajectories: 2,
            top_fraction: 0.25,
            ..PtrConfig::default()
        };
        let mut s = loaded(cfg);
        assert!(s
            .on_episode(&episode_with(0, 1, true, 40, |_| 0.0))
            .is_empty());
        // Another task's episode does not fill task 0's pool.
        assert!(s
            .on_episode(&episode_with(1, 2, true, 40, |_| 0.0))
            .is_empty());
        let sel = s.on_episode(&episode_with(0, 3, true, 40, |_| 10.0));
        assert_eq!(sel.len(), 20, "top quarter of 80 pooled transitions");
        assert!(
            sel.iter()
                .all(|(_, x)| x.trajectory_id == trajectory_id(3, 3) && x.task == 0),
            "all from the high-reward trajectory"
        );
        assert!(sel.windows(2).all(|w| w[0].0 >= w[1].0));
    }

    #[test]
    fn episodes_before_the_weights_are_counted() {
        let cfg = PtrConfig {
            success_threshold: 0.0,
            min_episodes: Some(1),
            ..PtrConfig::default()
        };
        let mut s = Scorer::new(cfg, &sac_config());
        assert!(s.on_episode(&episode(0, 0, false, 10)).is_empty());
        assert_eq!(s.unscored_no_weights, 1);
    }
}
