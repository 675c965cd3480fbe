//! TERL guidance (paper Sec. IV.C, Eq. 15): when the planner says the policy's action does not
//! bring the goal closer, execute the Action Network's action instead, with a probability that
//! decays over finished episodes.
//!
//! Rule, per actor step `t` of one environment, with `a = π(s_t)` and goal state `g = g(s_t)`:
//! `f_t = F(s_t, g, a)`; execute `AN(s_t, g)` iff `f_t ≥ f_{t−1}` **and** `u < σ^N`, `u ~ U[0, 1)`,
//! σ = 0.98, `N` = episodes this actor (environment) has finished; otherwise execute `a`.
//!
//! Reading of the paper: Eq. 15 writes `F(s_t, s_{t+1}, a_t) > F_{t−1}` with the goal in place of
//! `s_{t+1}` (the next state is unknown before acting; the text explains `F_{t−1}` as the distance
//! to the target "when the action is not executed"). We follow ARCHITECTURE.md: "not below" (≥),
//! and `f_{t−1}` is the previous step's `F(s_{t−1}, g, π(s_{t−1}))` — the value of the *policy*
//! action, whether or not the planner's action was executed. The first step of an episode has no
//! `f_{t−1}` and is never guided. The random number is drawn at every step (guided or not), so
//! the stream of draws does not depend on F.

use rand::Rng;
use serde::{Deserialize, Serialize};

/// Which part of the observation the goal replaces in [`goal_state`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalTarget {
    /// Object 1's position `obs[4..7]` (tasks that move an object).
    Object,
    /// The hand position `obs[0..3]` (tasks without an object to move, e.g. reach).
    Hand,
}

impl GoalTarget {
    /// The default choice for a Meta-World v3 task name: `Hand` for `reach` (its goal is a hand
    /// position), `Object` for every other task.
    pub fn for_task(name: &str) -> Self {
        match name.trim_end_matches("-v3") {
            "reach" => Self::Hand,
            _ => Self::Object,
        }
    }

    /// The observation range the goal is written into.
    pub fn range(self) -> std::ops::Range<usize> {
        match self {
            Self::Object => OBJECT_POS,
            Self::Hand => HAND_POS,
        }
    }
}

/// Where guidance takes its goal state from (the ARCHITECTURE.md config switch).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalSource {
    /// [`goal_state`]: the observation with the object (or hand) position set to the goal.
    #[default]
    ObsGoal,
    /// The final state of the nearest selected successful trajectory of this task (looked up by
    /// the actor from the TEP dataset; not computed in this crate).
    NearestSuccessfulFinal,
}

/// Hand position in a Meta-World observation.
pub const HAND_POS: std::ops::Range<usize> = 0..3;
/// Object 1 position in a Meta-World observation.
pub const OBJECT_POS: std::ops::Range<usize> = 4..7;
/// Goal position in a Meta-World observation (fully observable benchmarks).
pub const GOAL_POS: std::ops::Range<usize> = 36..39;

/// Goal state `g(s)`: a copy of `obs` whose object-1 position (or hand position) is replaced by
/// the goal position `obs[36..39]`, written into `out`. `obs` must have at least 39 entries.
pub fn goal_state_into(obs: &[f32], target: GoalTarget, out: &mut [f32]) {
    assert!(
        obs.len() >= GOAL_POS.end,
        "goal_state needs a Meta-World observation"
    );
    out.copy_from_slice(obs);
    out[target.range()].copy_from_slice(&obs[GOAL_POS]);
}

/// [`goal_state_into`] returning a new vector.
pub fn goal_state(obs: &[f32], target: GoalTarget) -> Vec<f32> {
    let mut out = vec![0.0; obs.len()];
    goal_state_into(obs, target, &mut out);
    out
}

/// Eq. 15 as a pure function: whether to execute the planner's action.
pub fn use_planner(f_t: f64, f_prev: Option<f64>, draw: f64, sigma: f64, episodes: u64) -> bool {
    match f_prev {
        Some(prev) => f_t >= prev && draw < guidance_probability(sigma, episodes),
        None => false,
    }
}

/// `σ^N`: the probability that a non-improving step is guided after `N` finished episodes.
pub fn guidance_probability(sigma: f64, episodes: u64) -> f64 {
    sigma.powf(episodes as f64)
}

/// Guidance settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceConfig {
    /// Decay σ of the guidance probability per finished episode (paper: 0.98).
    pub sigma: f64,
    /// Where the goal state comes from.
    pub goal_source: GoalSource,
}

impl Default for GuidanceConfig {
    fn default() -> Self {
        Self {
            sigma: 0.98,
            goal_source: GoalSource::ObsGoal,
        }
    }
}

/// Per-environment guidance state: the previous step's `f`, finished episodes, counters.
#[derive(Clone, Debug)]
pub struct Guidance {
    sigma: f64,
    prev: Option<f64>,
    episodes: u64,
    steps: u64,
    guided: u64,
}

impl Guidance {
    pub fn new(sigma: f64) -> Self {
        Self::with_episodes(sigma, 0)
    }

    /// State for an actor that has already finished `episodes` episodes (e.g. after a restart).
    pub fn with_episodes(sigma: f64, episodes: u64) -> Self {
        Self {
            sigma,
            prev: None,
            episodes,
            steps: 0,
            guided: 0,
        }
    }

    /// One step: `f_t = F(s_t, g, π(s_t))`; draws `u` from `rng` and returns whether to execute
    /// `AN(s_t, g)`. Remembers `f_t` as the next step's `f_{t−1}`.
    pub fn decide(&mut self, f_t: f64, rng: &mut impl Rng) -> bool {
        let draw: f64 = rng.gen();
        self.decide_with_draw(f_t, draw)
    }

    /// [`Guidance::decide`] with the uniform draw given.
    pub fn decide_with_draw(&mut self, f_t: f64, draw: f64) -> bool {
        let guided = use_planner(f_t, self.prev, draw, self.sigma, self.episodes);
        self.prev = Some(f_t);
        self.steps += 1;
        self.guided += guided as u64;
        guided
    }

    /// The episode ended: forget `f_{t−1}` and count it (`N += 1`).
    pub fn end_episode(&mut self) {
        self.prev = None;
        self.episodes += 1;
    }

    /// Current `σ^N`.
    pub fn probability(&self) -> f64 {
        guidance_probability(self.sigma, self.episodes)
    }

    /// Finished episodes `N`.
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// Steps decided and steps guided so far.
    pub fn counts(&self) -> (u64, u64) {
        (self.steps, self.guided)
    }

    /// Fraction of decided steps that were guided (0 before any step).
    pub fn rate(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.guided as f64 / self.steps as f64
        }
    }
}
