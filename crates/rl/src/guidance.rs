//! TERL guidance (paper Sec. IV.C, Eq. 15): when the planner says the policy's action does not
//! bring the goal closer, execute the Action Network's action instead, with a probability that
//! decays over finished episodes.
//!
//! Rule, per actor step `t` of one environment, with `a = π(s_t)` and goal state `g = g(s_t)`:
//! `f_t = F(s_t, g, a)`; execute `AN(s_t, g)` iff `f_t ≥ f_{t−1}` **and** `u < σ^N`, `u ~ U[0, 1)`,
//! σ = 0.98, `N` = episodes completed; otherwise execute `a`.
//!
//! **Which episodes `N` counts** ([`EpisodeCounter`], `[guidance] episode_counter`): by default
//! every episode the actor has completed, over all its environments — the paper's "the number
//! of episodes completed", for the agent that acts. The alternative, `"environment"`, counts
//! each environment's own episodes; with `E` environments per actor its guidance then decays
//! `E` times slower per episode of experience. Either way `N` counts from the first planner
//! version (see [`BatchGuidance::end_episode`]).
//!
//! Reading of the paper: Eq. 15 writes `F(s_t, s_{t+1}, a_t) > F_{t−1}` with the goal in place of
//! `s_{t+1}` (the next state is unknown before acting; the text explains `F_{t−1}` as the distance
//! to the target "when the action is not executed"). We follow ARCHITECTURE.md: "not below" (≥),
//! and `f_{t−1}` is the previous step's `F(s_{t−1}, g, π(s_{t−1}))` — the value of the *policy*
//! action, whether or not the planner's action was executed. The first step of an episode has no
//! `f_{t−1}` and is never guided. The random number is drawn at every step (guided or not), so
//! the stream of draws does not depend on F.

use crate::tep::{Planner, TepConfig};
use rand::Rng;
use serde::{Deserialize, Serialize};

/// Which part of the observation the goal replaces in [`goal_state`] (in both frames).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalTarget {
    /// Object 1's position: `obs[4..7]` and its previous-frame copy `obs[22..25]` (tasks that
    /// move an object).
    Object,
    /// The hand position: `obs[0..3]` and its previous-frame copy `obs[18..21]` (tasks without
    /// an object to move, e.g. reach).
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

    /// The current-frame observation range the goal is written into.
    pub fn range(self) -> std::ops::Range<usize> {
        match self {
            Self::Object => OBJECT_POS,
            Self::Hand => HAND_POS,
        }
    }

    /// The same quantity's range in the previous-frame copy `obs[18..36]`.
    pub fn previous_range(self) -> std::ops::Range<usize> {
        let r = self.range();
        r.start + FRAME_LEN..r.end + FRAME_LEN
    }
}

/// Which finished episodes `N` in `σ^N` counts (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EpisodeCounter {
    /// Episodes completed by the whole actor, all its environments together (the paper's
    /// "number of episodes completed"; default).
    #[default]
    Actor,
    /// Episodes completed by each environment on its own (`E` environments per actor decay
    /// `E` times slower per episode of the actor).
    Environment,
}

/// Values of one frame in a Meta-World observation: hand xyz, gripper opening, two objects as
/// position + quaternion (`crates/sim`'s `current_frame`). The observation is the current frame
/// `obs[0..18]`, the previous step's frame `obs[18..36]`, the goal `obs[36..39]`.
pub const FRAME_LEN: usize = 18;
/// Hand position in a Meta-World observation (current frame; `+ FRAME_LEN` in the previous one).
pub const HAND_POS: std::ops::Range<usize> = 0..3;
/// Object 1 position in a Meta-World observation (current frame; `+ FRAME_LEN` in the previous
/// one).
pub const OBJECT_POS: std::ops::Range<usize> = 4..7;
/// Goal position in a Meta-World observation (fully observable benchmarks).
pub const GOAL_POS: std::ops::Range<usize> = 36..39;

/// Goal state `g(s)`: a copy of `obs` whose object-1 position (or hand position) is replaced by
/// the goal position `obs[36..39]` in **both** frames — the current one (`obs[4..7]` or
/// `obs[0..3]`) and the previous-frame copy (`obs[22..25]` or `obs[18..21]`) — written into
/// `out`. `obs` must have at least 39 entries.
///
/// Both frames, because F is trained on hindsight goals that are real observations, whose two
/// frames differ by one step's motion; a goal whose previous frame still held the old position
/// would differ from its current frame by the whole distance to the goal, a state F never saw.
/// The goal state is one that has settled at the goal (object, or hand, at rest there).
pub fn goal_state_into(obs: &[f32], target: GoalTarget, out: &mut [f32]) {
    assert!(
        obs.len() >= GOAL_POS.end,
        "goal_state needs a Meta-World observation"
    );
    out.copy_from_slice(obs);
    out[target.range()].copy_from_slice(&obs[GOAL_POS]);
    out[target.previous_range()].copy_from_slice(&obs[GOAL_POS]);
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

/// What TERL guidance (Eq. 15) did at one environment step; all `false`/`None`/0 where the
/// planner could not act (no planner weights yet, or the task not validated by the gate).
///
/// The actor stamps it on each transition (the transport's `Transition` flags and fields) so the learner can report, per task, σ^N, how often `f_t ≥ f_{t−1}` held and how far AN's
/// action lies from the policy's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GuidanceStep {
    /// The planner may guide this environment now (weights loaded, task validated).
    pub active: bool,
    /// `σ^N` of the environment at this decision, in [0, 1] (0 when not `active`).
    pub probability: f64,
    /// The decision compared `f_t` with `f_{t−1}`: `Some(f_t ≥ f_{t−1})` (the condition of
    /// Eq. 15 that lets the planner act); `None` when F was not evaluated or there was no
    /// `f_{t−1}` (first step of an episode, or the previous step skipped F).
    pub not_improving: Option<bool>,
    /// Guided steps only: `‖AN(s, g) − π(s)‖₂` of the executed (clamped) action against the
    /// policy's, in action units (at most 2·√act_dim).
    pub action_gap: Option<f64>,
}

/// Where the goal state `g` of an episode comes from (`[guidance] goal_source`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GoalSource {
    /// The final state (at success) of the selected successful trajectory of the same task whose
    /// goal position is nearest this episode's, moved onto this episode's goal
    /// ([`GoalLibrary::goal_into`]); chosen at the
    /// episode's first step and fixed for the episode. A state the planner was trained to reach.
    #[default]
    FinalState,
    /// [`goal_state`] of the current observation, rebuilt every step (the object or hand moved
    /// to the goal, everything else as it is now). `"obs_goal"` in run files of earlier versions.
    #[serde(alias = "obs_goal")]
    Replace,
}

/// Guidance settings (`[guidance]`).
///
/// ```toml
/// sigma = 0.98
/// episode_counter = "actor"   # or "environment"
/// goal_source = "final_state" # or "replace"
/// min_spearman = 0.8
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GuidanceConfig {
    /// Decay σ of the guidance probability per finished episode, in [0, 1] (paper: 0.98).
    pub sigma: f64,
    /// Which episodes `N` of `σ^N` counts: `"actor"` (every episode the actor completed, the
    /// paper's reading; default) or `"environment"` (each environment's own). Either way `N`
    /// counts from the moment the task's planner was validated. The paper also says "the number
    /// of steps in one episode was set to 4096": with Meta-World's 500-step episodes we count
    /// episodes as episodes; `steps_per_episode` below gives the other reading.
    pub episode_counter: EpisodeCounter,
    /// When set, `N` counts blocks of this many environment steps instead of episodes (the
    /// paper's "4096 steps in one episode"); `None` (default) counts finished episodes.
    pub steps_per_episode: Option<u64>,
    /// Where the goal state comes from.
    pub goal_source: GoalSource,
    /// A task is guided only once F's Spearman ρ against the true step gap on that task's
    /// held-out selected trajectories reaches this ([`crate::planner_eval`]).
    pub min_spearman: f64,
    /// Held-out trajectories per task the learner keeps out of the TEP buffer for that check.
    pub validation_trajectories: usize,
    /// TEP updates between two checks.
    pub validate_every_updates: u64,
}

impl Default for GuidanceConfig {
    fn default() -> Self {
        Self {
            sigma: 0.98,
            episode_counter: EpisodeCounter::Actor,
            steps_per_episode: None,
            goal_source: GoalSource::FinalState,
            min_spearman: 0.8,
            validation_trajectories: 4,
            validate_every_updates: 200,
        }
    }
}

impl GuidanceConfig {
    /// Checks the values (σ in [0, 1], ρ threshold in [−1, 1], positive counts).
    pub fn validate(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.sigma) {
            return Err(format!("guidance sigma {} not in [0, 1]", self.sigma));
        }
        if !(-1.0..=1.0).contains(&self.min_spearman) {
            return Err(format!(
                "guidance min_spearman {} not in [-1, 1]",
                self.min_spearman
            ));
        }
        if self.validation_trajectories == 0 || self.validate_every_updates == 0 {
            return Err(
                "guidance validation_trajectories and validate_every_updates must be ≥ 1".into(),
            );
        }
        if self.steps_per_episode == Some(0) {
            return Err("guidance steps_per_episode must be ≥ 1".into());
        }
        Ok(())
    }
}

/// Fewest samples a selected trajectory needs to be held out for the planner check (the
/// learner's gate, and `terl planner train|eval --hold-out-trajectories`); shorter ones train.
pub const MIN_VALIDATION_STEPS: usize = 10;

/// Goal states per task the learner sends with the planner (the most recent ones).
pub const GOAL_LIBRARY_PER_TASK: usize = 32;

/// Final states of selected successful trajectories, per task: the goal states of
/// [`GoalSource::FinalState`]. Row `i` is task `tasks[i]`'s state `states[i·obs_dim..]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GoalLibrary {
    /// Observation length of every state.
    pub obs_dim: usize,
    /// Task index of each goal state, one per row.
    pub tasks: Vec<u32>,
    /// The goal states, `[len, obs_dim]` row-major.
    pub states: Vec<f32>,
}

impl GoalLibrary {
    /// An empty library of states of `obs_dim` values.
    pub fn new(obs_dim: usize) -> Self {
        Self {
            obs_dim,
            ..Self::default()
        }
    }

    /// Number of goal states, over all tasks.
    pub fn len(&self) -> usize {
        self.tasks.len()
    }

    /// Whether the library holds no goal state.
    pub fn is_empty(&self) -> bool {
        self.tasks.is_empty()
    }

    /// Adds the final state of a successful trajectory of `task`.
    pub fn push(&mut self, task: u32, state: &[f32]) {
        assert_eq!(state.len(), self.obs_dim, "goal library state width");
        self.tasks.push(task);
        self.states.extend_from_slice(state);
    }

    /// Whether `task` has a goal state.
    pub fn has_task(&self, task: u32) -> bool {
        self.tasks.contains(&task)
    }

    /// The goal state for an episode of `task` that starts at `obs`: the library's state of that
    /// task whose goal position (`[36..39]`) is nearest `obs`'s, moved by the difference of the two
    /// goal positions (hand and object 1 in both frames, so the final configuration keeps its
    /// shape: an object set onto the new goal with the hand left at the old one is a state no
    /// trajectory reaches) and with `obs`'s goal, written into `out` (the same for hand and object tasks).
    /// `false` (and `out` untouched) when the task has none.
    pub fn goal_into(&self, task: u32, obs: &[f32], out: &mut [f32]) -> bool {
        let od = self.obs_dim;
        let goal = &obs[GOAL_POS];
        let dist = |i: usize| -> f32 {
            self.states[i * od..(i + 1) * od][GOAL_POS]
                .iter()
                .zip(goal)
                .map(|(a, b)| (a - b) * (a - b))
                .sum()
        };
        let best = (0..self.len())
            .filter(|&i| self.tasks[i] == task)
            .min_by(|&a, &b| dist(a).total_cmp(&dist(b)));
        let Some(i) = best else {
            return false;
        };
        let state = &self.states[i * od..(i + 1) * od];
        out.copy_from_slice(state);
        // The whole final configuration moved with the goal: hand and object 1, both frames.
        for k in 0..3 {
            let delta = goal[k] - state[GOAL_POS.start + k];
            for r in [HAND_POS, OBJECT_POS] {
                out[r.start + k] += delta;
                out[r.start + FRAME_LEN + k] += delta;
            }
        }
        out[GOAL_POS].copy_from_slice(goal);
        true
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
    /// A fresh environment state with decay base `sigma` (σ of `σ^N`, 0.98 in the paper) and
    /// no finished episode (`N = 0`, so `σ^N = 1`).
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

    /// One step decided without evaluating F, because the draw made guidance impossible both
    /// now and at the next step (see [`BatchGuidance`]): never guided, and the next step has no
    /// `f_{t−1}` (it is not guided either, which its own draw already decided).
    pub fn skip(&mut self) {
        self.prev = None;
        self.steps += 1;
    }

    /// The episode ended: forget `f_{t−1}` and count it (`N += 1`).
    pub fn end_episode(&mut self) {
        self.prev = None;
        self.episodes += 1;
    }

    /// Another environment of the same actor completed an episode and `N` counts the actor's
    /// episodes ([`EpisodeCounter::Actor`]): `N += 1`, this episode's `f_{t−1}` is kept.
    pub fn count_episode(&mut self) {
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

/// Eq. 15 for an actor's `E` environments with one planner, computing only what a decision can
/// use:
///
/// - One uniform draw `u_t` per actor step, shared by its environments, taken one step ahead.
///   Each environment still compares a uniform draw with its own `σ^N`, so each is guided with
///   the rule's probability; sharing the draw only correlates the environments of one actor,
///   and makes F skippable for the whole batch at once (a small-batch F costs about the same
///   for 1 row as for 8: it is bound by reading the weights).
/// - An environment needs `f_t = F(s_t, g, π(s_t))` only if `u_t < σ^N` (this step may be
///   guided: compare with `f_{t−1}`) or `u_{t+1} < σ^N` (the next step may be: it compares with
///   `f_t`); otherwise F is skipped for it ([`Guidance::skip`]). Decisions are exactly those of
///   evaluating F everywhere with the same draws, and the cost decays with `σ^N`: about `2σ^N`
///   of the steps evaluate F at all.
/// - `AN(s_t, g)` runs only on the rows that are guided.
///
/// F and AN run on the needed rows gathered into one small batch each.
#[derive(Debug)]
pub struct BatchGuidance {
    planner: Planner,
    per_env: Vec<Guidance>,
    counter: EpisodeCounter,
    targets: Vec<GoalTarget>,
    /// Task index of each environment (into the run's task list and the planner's gate).
    env_tasks: Vec<u32>,
    /// Per environment: its task passed the planner check, so it may be guided.
    enabled: Vec<bool>,
    /// Whether a gate was ever given ([`Self::set_validated`]); without one every task is
    /// guided (tools and planners trained offline on the run's own tasks).
    gated: bool,
    goal_source: GoalSource,
    library: GoalLibrary,
    /// The episode's fixed goal state per environment ([`GoalSource::FinalState`]).
    episode_goals: Vec<f32>,
    /// Whether `episode_goals[env]` holds this episode's goal.
    have_goal: Vec<bool>,
    /// Decisions with an `f_{t−1}` and how many of them had `f_t ≥ f_{t−1}`.
    compared: u64,
    non_improving: u64,
    /// Sum over guided rows of ‖AN(s, g) − π(s)‖ (Euclidean, action units).
    action_gap_sum: f64,
    next_draw: Option<f64>,
    guided: Vec<bool>,
    /// Per environment: what guidance did at the last [`Self::apply`].
    steps: Vec<GuidanceStep>,
    obs_dim: usize,
    act_dim: usize,
    rows: Vec<usize>,
    draws: Vec<f64>,
    obs: Vec<f32>,
    goals: Vec<f32>,
    actions: Vec<f32>,
    reach: Vec<f32>,
    planned: Vec<f32>,
    f_rows: u64,
    an_rows: u64,
    an_rows_window: u64,
}

impl BatchGuidance {
    /// Guidance for environments whose goal targets are `targets` (one per environment), with a
    /// planner shaped by `config` (weights are a placeholder until [`Self::planner_mut`] loads
    /// real ones; nothing is guided before that).
    pub fn new(config: &TepConfig, sigma: f64, targets: Vec<GoalTarget>) -> Self {
        let n = targets.len();
        let (od, ad) = (config.obs_dim, config.act_dim);
        Self {
            planner: Planner::new(config, n.max(1)),
            per_env: (0..n).map(|_| Guidance::new(sigma)).collect(),
            counter: EpisodeCounter::default(),
            next_draw: None,
            guided: vec![false; n],
            steps: vec![GuidanceStep::default(); n],
            obs_dim: od,
            act_dim: ad,
            rows: Vec::with_capacity(n),
            draws: vec![0.0; n],
            obs: vec![0.0; n * od],
            goals: vec![0.0; n * od],
            actions: vec![0.0; n * ad],
            reach: vec![0.0; n],
            planned: vec![0.0; n * ad],
            env_tasks: vec![0; n],
            enabled: vec![true; n],
            gated: false,
            goal_source: GoalSource::Replace,
            library: GoalLibrary::new(od),
            episode_goals: vec![0.0; n * od],
            have_goal: vec![false; n],
            compared: 0,
            non_improving: 0,
            action_gap_sum: 0.0,
            targets,
            f_rows: 0,
            an_rows: 0,
            an_rows_window: 0,
        }
    }

    /// The task index of each environment (required for a gate or a goal library).
    pub fn with_tasks(mut self, env_tasks: Vec<u32>) -> Self {
        assert_eq!(
            env_tasks.len(),
            self.per_env.len(),
            "one task per environment"
        );
        self.env_tasks = env_tasks;
        self
    }

    /// Chooses the goal source (default [`GoalSource::Replace`] until a library arrives).
    pub fn with_goal_source(mut self, source: GoalSource) -> Self {
        self.goal_source = source;
        self
    }

    /// The goal states of [`GoalSource::FinalState`]; an environment whose task has none uses
    /// [`goal_state`] of its observation. Takes effect at each environment's next episode.
    pub fn set_library(&mut self, library: GoalLibrary) {
        self.library = library;
    }

    /// Which tasks passed the planner check (`validated[task]`). An environment is guided only
    /// once its task has; its `N` counts from that moment (a task validated now starts at
    /// `σ^0 = 1`). Validation latches: a task once validated stays guided.
    pub fn set_validated(&mut self, validated: &[bool]) {
        let first = !self.gated;
        self.gated = true;
        for i in 0..self.per_env.len() {
            let ok = validated
                .get(self.env_tasks[i] as usize)
                .copied()
                .unwrap_or(false);
            let was = self.enabled[i] && !first;
            if ok && !was {
                self.per_env[i] = Guidance::new(self.per_env[i].sigma);
                self.have_goal[i] = false;
            }
            self.enabled[i] = ok || was;
        }
    }

    /// Whether environment `env` may be guided (its task passed the check).
    pub fn enabled(&self, env: usize) -> bool {
        self.enabled[env]
    }

    /// `(decisions with an f_{t−1}, of which f_t ≥ f_{t−1}, mean ‖AN − π‖ over guided rows)`
    /// since the last call; counters restart.
    pub fn take_decision_stats(&mut self) -> (u64, u64, f64) {
        let mean = if self.an_rows_window > 0 {
            self.action_gap_sum / self.an_rows_window as f64
        } else {
            0.0
        };
        let out = (self.compared, self.non_improving, mean);
        self.compared = 0;
        self.non_improving = 0;
        self.action_gap_sum = 0.0;
        self.an_rows_window = 0;
        out
    }

    /// Chooses which episodes `N` counts (default [`EpisodeCounter::Actor`]).
    pub fn with_counter(mut self, counter: EpisodeCounter) -> Self {
        self.counter = counter;
        self
    }

    /// The episode counter in use.
    pub fn counter(&self) -> EpisodeCounter {
        self.counter
    }

    /// `σ^N` of environment `env` now.
    pub fn probability(&self, env: usize) -> f64 {
        self.per_env[env].probability()
    }

    /// Starts every environment at `episodes` finished episodes (benchmarks, restarts).
    pub fn with_episodes(mut self, episodes: u64) -> Self {
        for g in &mut self.per_env {
            *g = Guidance::with_episodes(g.sigma, episodes);
        }
        self
    }

    /// The planner (F and AN) the rule consults.
    pub fn planner(&self) -> &Planner {
        &self.planner
    }

    /// Mutable access to the planner, e.g. to load new weights into it.
    pub fn planner_mut(&mut self) -> &mut Planner {
        &mut self.planner
    }

    /// Whether planner weights were loaded (version > 0): guidance only acts then.
    pub fn active(&self) -> bool {
        self.planner.version() > 0
    }

    /// Which environments executed the planner's action at the last [`Self::apply`].
    pub fn guided(&self) -> &[bool] {
        &self.guided
    }

    /// What guidance did for environment `env` at the last [`Self::apply`].
    pub fn step(&self, env: usize) -> GuidanceStep {
        self.steps[env]
    }

    /// `(decisions, F rows evaluated, AN rows evaluated)` so far.
    pub fn counts(&self) -> (u64, u64, u64) {
        let decisions = self.per_env.iter().map(|g| g.counts().0).sum();
        (decisions, self.f_rows, self.an_rows)
    }

    /// Replaces the rows of `actions` (the policy's, `E × act_dim`) that Eq. 15 guides with
    /// `AN(s, g(s))`; `obs` is `E × obs_dim`. Returns how many rows were guided.
    pub fn apply(&mut self, obs: &[f32], actions: &mut [f32], rng: &mut impl Rng) -> usize {
        let (od, ad) = (self.obs_dim, self.act_dim);
        let n = self.per_env.len();
        assert!(
            obs.len() == n * od && actions.len() == n * ad,
            "one row per environment"
        );
        self.guided.fill(false);
        self.steps.fill(GuidanceStep::default());
        if !self.active() {
            return 0;
        }
        self.rows.clear();
        let u_t = self.next_draw.take().unwrap_or_else(|| rng.gen());
        let u_next: f64 = rng.gen();
        self.next_draw = Some(u_next);
        for i in 0..n {
            if !self.enabled[i] {
                continue;
            }
            let p = self.per_env[i].probability();
            self.steps[i].active = true;
            self.steps[i].probability = p;
            if u_t < p || u_next < p {
                self.draws[self.rows.len()] = u_t;
                self.rows.push(i);
            } else {
                self.per_env[i].skip();
            }
        }
        let k = self.rows.len();
        if k == 0 {
            return 0;
        }
        for (j, &i) in self.rows.iter().enumerate() {
            let o = &obs[i * od..(i + 1) * od];
            self.obs[j * od..(j + 1) * od].copy_from_slice(o);
            let g = &mut self.goals[j * od..(j + 1) * od];
            let fixed = self.goal_source == GoalSource::FinalState
                && (self.have_goal[i]
                    || self.library.goal_into(
                        self.env_tasks[i],
                        o,
                        &mut self.episode_goals[i * od..(i + 1) * od],
                    ));
            if fixed {
                self.have_goal[i] = true;
                g.copy_from_slice(&self.episode_goals[i * od..(i + 1) * od]);
            } else {
                goal_state_into(o, self.targets[i], g);
            }
            self.actions[j * ad..(j + 1) * ad].copy_from_slice(&actions[i * ad..(i + 1) * ad]);
        }
        self.planner.reach(
            &self.obs[..k * od],
            &self.goals[..k * od],
            &self.actions[..k * ad],
            &mut self.reach[..k],
        );
        self.f_rows += k as u64;
        // Compact the guided rows to the front of the gathered buffers.
        let mut m = 0;
        for j in 0..k {
            let i = self.rows[j];
            if let Some(prev) = self.per_env[i].prev {
                let not_improving = f64::from(self.reach[j]) >= prev;
                self.compared += 1;
                self.non_improving += u64::from(not_improving);
                self.steps[i].not_improving = Some(not_improving);
            }
            if self.per_env[i].decide_with_draw(f64::from(self.reach[j]), self.draws[j]) {
                self.guided[i] = true;
                self.rows[m] = i;
                self.obs.copy_within(j * od..(j + 1) * od, m * od);
                self.goals.copy_within(j * od..(j + 1) * od, m * od);
                m += 1;
            }
        }
        if m == 0 {
            return 0;
        }
        self.planner.actions(
            &self.obs[..m * od],
            &self.goals[..m * od],
            &mut self.planned[..m * ad],
        );
        self.an_rows += m as u64;
        self.an_rows_window += m as u64;
        for (j, &i) in self.rows[..m].iter().enumerate() {
            let mut gap = 0.0f64;
            for (d, &p) in actions[i * ad..(i + 1) * ad]
                .iter_mut()
                .zip(&self.planned[j * ad..(j + 1) * ad])
            {
                let p = p.clamp(-1.0, 1.0);
                gap += f64::from(p - *d).powi(2);
                *d = p;
            }
            self.action_gap_sum += gap.sqrt();
            self.steps[i].action_gap = Some(gap.sqrt());
        }
        m
    }

    /// Environment `env` finished an episode: its `f_{t−1}` is forgotten, and `N` grows by one
    /// for every environment ([`EpisodeCounter::Actor`]) or for `env` only
    /// ([`EpisodeCounter::Environment`]). `N` counts episodes since guidance became active (the
    /// first planner version): counting earlier ones would decay the probability to nothing
    /// before a planner exists.
    pub fn end_episode(&mut self, env: usize) {
        self.have_goal[env] = false;
        if !self.active() || !self.enabled[env] {
            return;
        }
        self.per_env[env].end_episode();
        if self.counter == EpisodeCounter::Actor {
            for (i, g) in self.per_env.iter_mut().enumerate() {
                if i != env && self.enabled[i] {
                    g.count_episode();
                }
            }
        }
    }
}
