//! Meta-World v3 tasks in Rust, behaving like `metaworld==3.1.1` on MuJoCo 3.3.7 (checked by
//! replaying Python traces, see `tests/parity.rs`).
//!
//! An [`Env`] is one task instance: fully observable 39-dim observation (hand xyz, gripper
//! opening, two objects as position + quaternion, the previous frame's 18 values, goal), 4-dim
//! action (mocap delta in [-1, 1] scaled by 1 cm, gripper effort), frame skip 5, the task's
//! v2-style reward and success rule, truncation at 500 steps.
//!
//! Reset takes an explicit `rand_vec` (Meta-World's goal/object randomisation vector) or draws
//! one: [`goal_variations`] gives the 50 reproducible variations of a task for a seed.

pub mod policies;
pub mod reward;
pub mod scene;
pub mod tasks;

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex, OnceLock};

use rand::{Rng, SeedableRng};

use crate::error::{Result, SimError};
use crate::mujoco::{Model, Simulation};
pub use scene::{Density, Scene, FRAME_SKIP, TARGET_RADIUS};
pub use tasks::{task_names, task_set, task_set_names, TaskSpec};

/// The benchmark's fixed sizes, defined once in `terl_spaces` (which the message crates share
/// without this crate's FFI): observation and action widths, episode length, goal variations.
pub use terl_spaces::{ACTION_DIM, MAX_PATH_LENGTH, NUM_VARIATIONS, OBS_DIM};

const HAND_SPACE_LOW: [f64; 3] = [-0.525, 0.348, -0.0525];
const HAND_SPACE_HIGH: [f64; 3] = [0.525, 1.025, 0.7];

/// The outcome of one step's reward computation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Eval {
    /// The task's shaped reward for this step (v2-style).
    pub reward: f64,
    /// The task's success criterion (Meta-World's `info["success"]`).
    pub success: bool,
}

/// Behaviour of one Meta-World task on top of the shared [`Scene`].
pub trait Task: Send + std::fmt::Debug {
    /// Static description: model file, bounds, randomisation ranges.
    fn spec(&self) -> &'static TaskSpec;
    /// `reset_model` without the final `_get_obs`. Must set `scene.target_pos` and
    /// `scene.obj_init_pos`.
    fn reset_model(&mut self, scene: &mut Scene, rand_vec: &[f64]) -> Result<()>;
    /// Object positions and quaternions, zero padded (obs[4..18]).
    fn objects(&self, scene: &Scene, out: &mut [f64; 14]);
    /// Reward and success of the (clipped) observation and the action as given.
    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], action: &[f32; ACTION_DIM])
        -> Eval;
    /// Whether `evaluate` will read contacts or constraint forces for this (clipped)
    /// observation: then the step ends with a full `mj_forward`, as in Python, instead of only
    /// the kinematics pass. Asked every step, so a task whose success reads contacts only in
    /// some states (stick-push: once the stick is held near the goal) pays for the full pass
    /// only there.
    fn reads_contacts(&self, _scene: &Scene, _obs: &[f64; OBS_DIM]) -> bool {
        false
    }
}

/// What [`Env::step`] returns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// The observation after the step, clipped to Meta-World's observation space.
    pub obs: [f64; OBS_DIM],
    /// The task's shaped reward for the step (0 on an unstable step).
    pub reward: f64,
    /// The task's success criterion after the step (Meta-World's `info["success"]`).
    pub success: bool,
    /// The 500-step time limit was reached (or the physics went unstable).
    pub truncated: bool,
    /// MuJoCo reported a non-finite state during this step; the episode was cut short.
    pub unstable: bool,
}

/// Folder with Meta-World's XML/STL assets.
pub fn assets_dir() -> PathBuf {
    std::env::var_os("TERL_METAWORLD_ASSETS")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("TERL_METAWORLD_ASSETS_DEFAULT")))
}

/// Default size of every Meta-World simulation's `mjData` arena (contacts, constraint rows and
/// MuJoCo's stack), in bytes: about 2× the largest peak (`mjData.maxuse_arena`) measured over
/// random and scripted rollouts of all 50 tasks (see `docs/results/env-memory/`), rounded up.
/// MuJoCo's own guess from the scenes' `<size>` (none given) is 14.7 MB.
pub const DEFAULT_ARENA_BYTES: usize = 1 << 20;

/// The arena size simulations get: `TERL_MUJOCO_ARENA_BYTES` if set to a positive integer,
/// else [`DEFAULT_ARENA_BYTES`].
pub fn arena_bytes() -> usize {
    std::env::var("TERL_MUJOCO_ARENA_BYTES")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|n| *n > 0)
        .unwrap_or(DEFAULT_ARENA_BYTES)
}

/// Compiles a task's scene for sharing: the arena of [`arena_bytes`] and the pages only
/// rendering reads given back ([`Model::release_render_data`]).
fn compile(xml: &str) -> Result<Model> {
    let dir = assets_dir();
    let path = dir.join(xml);
    if !path.exists() {
        return Err(SimError::AssetsMissing { path: dir });
    }
    let mut model = Model::from_xml(&path)?;
    model.set_arena_bytes(arena_bytes());
    let released = model.release_render_data();
    tracing::debug!(
        xml,
        buffer_bytes = model.buffer_bytes(),
        released,
        "compiled Meta-World scene"
    );
    Ok(model)
}

/// The process's compiled model of a scene, shared by every environment of the tasks using it
/// (compiled once, on first use; kept until the process ends).
pub fn shared_model(xml: &str) -> Result<Arc<Model>> {
    static CACHE: OnceLock<Mutex<HashMap<String, Arc<Model>>>> = OnceLock::new();
    let cache = CACHE.get_or_init(Default::default);
    let mut cache = cache.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(model) = cache.get(xml) {
        return Ok(Arc::clone(model));
    }
    let model = Arc::new(compile(xml)?);
    cache.insert(xml.to_string(), Arc::clone(&model));
    Ok(model)
}

/// One Meta-World task instance.
#[derive(Debug)]
pub struct Env {
    scene: Scene,
    task: Box<dyn Task>,
    spec: &'static TaskSpec,
    prev: [f64; 18],
    steps: u32,
    rand_vec: Vec<f64>,
    needs_reset: bool,
    instability_events: u64,
}

impl Env {
    /// Creates the task by its Meta-World v3 name (e.g. `"reach-v3"`); reset before stepping.
    pub fn new(task: &str) -> Result<Self> {
        let spec = tasks::constructor(task)?.spec;
        Self::with_model(task, &shared_model(spec.xml)?)
    }

    /// Like [`Env::new`] but over a model compiled for this env alone, as MuJoCo compiles it
    /// (full arrays, the scene's own arena size): the reference the shared path is tested
    /// against.
    #[doc(hidden)]
    pub fn new_unshared(task: &str) -> Result<Self> {
        Self::for_rendering(task)
    }

    /// An environment that can be drawn by [`crate::render::Renderer`]: like [`Env::new`], but
    /// over a model of its own that keeps the arrays only rendering reads (meshes' faces and
    /// normals, textures; ~20 MB more than a shared environment). It steps exactly like
    /// [`Env::new`]'s (the parity tests compare the two).
    pub fn for_rendering(task: &str) -> Result<Self> {
        let spec = tasks::constructor(task)?.spec;
        let dir = assets_dir();
        let path = dir.join(spec.xml);
        if !path.exists() {
            return Err(SimError::AssetsMissing { path: dir });
        }
        Self::with_model(task, &Arc::new(Model::from_xml(&path)?))
    }

    fn with_model(task: &str, model: &Arc<Model>) -> Result<Self> {
        let make = tasks::constructor(task)?;
        let spec = make.spec;
        let sim = Simulation::new(model)?;
        let mut scene = Scene::new(sim, spec.mocap_low(), spec.mocap_high())?;
        scene.hand_init_pos = spec.hand_init_pos;
        scene.model_id = name_hash(spec.xml);
        let task = (make.build)(&scene)?;
        Ok(Self {
            scene,
            task,
            spec,
            prev: [0.0; 18],
            steps: 0,
            rand_vec: Vec::new(),
            needs_reset: true,
            instability_events: 0,
        })
    }

    /// The task's static description (model file, bounds, randomisation ranges).
    pub fn spec(&self) -> &'static TaskSpec {
        self.spec
    }
    /// The task's Meta-World v3 name, e.g. `"reach-v3"`.
    pub fn name(&self) -> &'static str {
        self.spec.name
    }
    /// The `rand_vec` of the current episode.
    pub fn rand_vec(&self) -> &[f64] {
        &self.rand_vec
    }
    /// Steps taken in the current episode.
    pub fn steps(&self) -> u32 {
        self.steps
    }
    /// Times the physics went unstable (and the episode was cut short) since creation.
    pub fn instability_events(&self) -> u64 {
        self.instability_events
    }
    /// The shared scene state (hand, gripper, goal, object start), read-only.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }
    /// The compiled model this env steps, shared with the process's other envs of its scene.
    pub fn model(&self) -> &Arc<Model> {
        self.scene.sim.shared_model()
    }

    /// Peak `mjData` arena use since the last reset, bytes (`mjData.maxuse_arena`), and the
    /// arena's size (`mjData.narena`).
    pub fn arena_use(&self) -> (usize, usize) {
        (
            self.scene.sim.arena_peak_bytes(),
            self.scene.sim.arena_bytes(),
        )
    }
    /// Peak contacts and constraint rows since the last reset (`maxuse_con`, `maxuse_efc`).
    pub fn peak_contacts_constraints(&self) -> (usize, usize) {
        self.scene.sim.peak_contacts_constraints()
    }

    fn check_arena(&mut self, before: i64) -> Result<()> {
        if self.scene.sim.arena_overflow_count() > before {
            self.needs_reset = true;
            return Err(SimError::ArenaFull {
                task: self.spec.name,
                arena_bytes: self.scene.sim.arena_bytes(),
                peak_bytes: self.scene.sim.arena_peak_bytes(),
            });
        }
        Ok(())
    }
    /// Current goal (obs[36..39]).
    pub fn goal(&self) -> [f64; 3] {
        self.scene.target_pos
    }

    /// Checks a `rand_vec` against the task's length, ranges and rejection rule.
    pub fn validate_rand_vec(&self, rand_vec: &[f64]) -> Result<()> {
        validate_rand_vec(self.spec, rand_vec)
    }

    /// Resets to the state Meta-World reaches with this `rand_vec`; returns the observation.
    pub fn reset(&mut self, rand_vec: &[f64]) -> Result<[f64; OBS_DIM]> {
        self.validate_rand_vec(rand_vec)?;
        self.rand_vec.clear();
        self.rand_vec.extend_from_slice(rand_vec);
        // Python runs reset_model on the old data, then mj_resetData, then reset_model again;
        // the first pass matters only through the model fields it writes.
        self.scene.physics = false;
        let first = self.task.reset_model(&mut self.scene, rand_vec);
        self.scene.physics = true;
        first?;
        self.scene.sim.reset_data();
        self.task.reset_model(&mut self.scene, rand_vec)?;
        // mj_resetData cleared the warning counters, so any count is from this reset.
        self.check_arena(0)?;
        self.steps = 0;
        self.needs_reset = false;
        let mut obs = [0.0; OBS_DIM];
        self.current_frame(&mut obs);
        let (cur, rest) = obs.split_at_mut(18);
        rest[..18].copy_from_slice(cur);
        self.prev.copy_from_slice(cur);
        obs[36..39].copy_from_slice(&self.scene.target_pos);
        Ok(obs)
    }

    /// Resets with a fresh `rand_vec` drawn from the task's ranges.
    pub fn reset_random(&mut self, rng: &mut impl Rng) -> Result<[f64; OBS_DIM]> {
        let rv = sample_rand_vec(self.spec, rng);
        self.reset(&rv)
    }

    /// Resets to goal variation `index` (0..50) of [`goal_variations`]`(task, seed)`.
    pub fn reset_variation(&mut self, seed: u64, index: usize) -> Result<[f64; OBS_DIM]> {
        let vars = goal_variations(self.spec.name, seed)?;
        let rv = vars.get(index).ok_or_else(|| SimError::OutOfRange {
            what: "goal variation index",
            detail: format!("{index} not in 0..{NUM_VARIATIONS}"),
        })?;
        self.reset(rv)
    }

    /// Physics only: the action's mocap move and gripper control, then the frame-skipped
    /// `mj_step`s, without observation, reward or bookkeeping. The lower bound of a step's
    /// cost, used by the benchmark (`terl bench env`, crate `terl-bench`).
    pub fn physics_only_step(&mut self, action: &[f32; ACTION_DIM]) {
        self.scene
            .apply_xyz_action([action[0], action[1], action[2]]);
        let grip = f64::from(action[3]);
        self.scene.do_simulation([grip, -grip], FRAME_SKIP);
    }

    /// Turns the process-wide hand-reset cache on or off for this env (on by default). Off,
    /// every reset runs the hand reset's 250 physics steps; results are identical either way.
    pub fn set_hand_reset_cache(&mut self, enabled: bool) {
        self.scene.hand_reset_cache = enabled;
    }

    /// Fault injection for tests of the instability path: puts a NaN into the velocities, which
    /// MuJoCo detects on the next step (`mjWARN_BADQVEL`) and answers by resetting its data.
    #[doc(hidden)]
    pub fn inject_nan_velocity(&mut self) {
        self.scene.sim.qvel_mut()[0] = f64::NAN;
    }

    fn current_frame(&self, out: &mut [f64]) {
        out[..3].copy_from_slice(&self.scene.hand_pos());
        out[3] = self.scene.gripper_distance_apart();
        let mut objects = [0.0; 14];
        self.task.objects(&self.scene, &mut objects);
        out[4..18].copy_from_slice(&objects);
    }

    /// Applies one action (length 4, finite; xyz clipped to [-1, 1], gripper as given).
    pub fn step(&mut self, action: &[f32]) -> Result<Step> {
        if action.len() != ACTION_DIM {
            return Err(SimError::Length {
                what: "action",
                got: action.len(),
                expected: ACTION_DIM,
            });
        }
        if let Some(index) = action.iter().position(|a| !a.is_finite()) {
            return Err(SimError::NonFinite {
                what: "action",
                index,
            });
        }
        if self.needs_reset {
            return Err(SimError::EpisodeOver(self.steps));
        }
        let action: [f32; ACTION_DIM] = action.try_into().expect("length checked");
        let before = self.scene.sim.instability_count();
        let arena_before = self.scene.sim.arena_overflow_count();
        self.scene
            .apply_xyz_action([action[0], action[1], action[2]]);
        let grip = f64::from(action[3]);
        self.scene.do_simulation([grip, -grip], FRAME_SKIP);
        self.steps += 1;
        self.check_arena(arena_before)?;
        // Python calls mj_forward here. Observations and rewards read only poses (contact
        // forces feed only Python's `grasp_success` info, not reward or success), and
        // mj_forward changes no state the next mj_step uses, so the kinematics pass suffices;
        // the parity traces check both claims on every task. A task whose success reads
        // contact forces (stick-push) gets the full pass, below, in the states where it does;
        // the full pass recomputes the same kinematics, so the observation stays valid.
        self.scene.sim.kinematics();

        let mut obs = [0.0; OBS_DIM];
        self.current_frame(&mut obs);
        obs[18..36].copy_from_slice(&self.prev);
        obs[36..39].copy_from_slice(&self.scene.target_pos);
        self.prev.copy_from_slice(&obs[..18]);
        clip_observation(&mut obs, self.spec);

        let unstable =
            self.scene.sim.instability_count() > before || obs.iter().any(|v| !v.is_finite());
        if unstable {
            self.instability_events += 1;
            self.needs_reset = true;
            tracing::warn!(
                task = self.spec.name,
                step = self.steps,
                "physics went unstable; the episode is cut short and the env must reset"
            );
            for v in obs.iter_mut().filter(|v| !v.is_finite()) {
                *v = 0.0;
            }
            return Ok(Step {
                obs,
                reward: 0.0,
                success: false,
                truncated: true,
                unstable: true,
            });
        }
        if self.task.reads_contacts(&self.scene, &obs) {
            self.scene.sim.forward();
            self.check_arena(arena_before)?;
        }
        let eval = self.task.evaluate(&self.scene, &obs, &action);
        let truncated = self.steps >= MAX_PATH_LENGTH;
        self.needs_reset = truncated;
        Ok(Step {
            obs,
            reward: eval.reward,
            success: eval.success,
            truncated,
            unstable: false,
        })
    }
}

fn clip_observation(obs: &mut [f64; OBS_DIM], spec: &TaskSpec) {
    for half in [0, 18] {
        for i in 0..3 {
            obs[half + i] = obs[half + i].clamp(HAND_SPACE_LOW[i], HAND_SPACE_HIGH[i]);
        }
        obs[half + 3] = obs[half + 3].clamp(-1.0, 1.0);
    }
    for i in 0..3 {
        obs[36 + i] = obs[36 + i].clamp(spec.goal_low[i], spec.goal_high[i]);
    }
}

fn validate_rand_vec(spec: &TaskSpec, rv: &[f64]) -> Result<()> {
    let expected = spec.rand_low.len();
    if rv.len() != expected {
        return Err(SimError::Length {
            what: "rand_vec",
            got: rv.len(),
            expected,
        });
    }
    if let Some(index) = rv.iter().position(|v| !v.is_finite()) {
        return Err(SimError::NonFinite {
            what: "rand_vec",
            index,
        });
    }
    for (i, v) in rv.iter().enumerate() {
        if *v < spec.rand_low[i] || *v > spec.rand_high[i] {
            return Err(SimError::OutOfRange {
                what: "rand_vec",
                detail: format!(
                    "{}: entry {i} = {v} not in [{}, {}]",
                    spec.name, spec.rand_low[i], spec.rand_high[i]
                ),
            });
        }
    }
    if !(spec.rand_vec_ok)(rv) {
        return Err(SimError::OutOfRange {
            what: "rand_vec",
            detail: format!(
                "{}: violates the task's placement rule (object and goal too close)",
                spec.name
            ),
        });
    }
    Ok(())
}

fn sample_rand_vec(spec: &TaskSpec, rng: &mut impl Rng) -> Vec<f64> {
    loop {
        let rv: Vec<f64> = spec
            .rand_low
            .iter()
            .zip(spec.rand_high)
            .map(|(lo, hi)| {
                if lo < hi {
                    rng.gen_range(*lo..*hi)
                } else {
                    *lo
                }
            })
            .collect();
        if (spec.rand_vec_ok)(&rv) {
            return rv;
        }
    }
}

fn name_hash(name: &str) -> u64 {
    // FNV-1a: stable across platforms and releases (unlike std's hasher).
    name.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The 50 goal variations of a task for a seed: `rand_vec`s drawn uniformly from Meta-World's
/// object/goal ranges with the task's rejection rule, by ChaCha8 seeded with
/// `seed ^ fnv1a(task name)`. Same task and seed give the same list on every machine.
pub fn goal_variations(task: &str, seed: u64) -> Result<Vec<Vec<f64>>> {
    let spec = tasks::constructor(task)?.spec;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ name_hash(spec.name));
    Ok((0..NUM_VARIATIONS)
        .map(|_| sample_rand_vec(spec, &mut rng))
        .collect())
}
