//! The task registry: every implemented Meta-World v3 task and the benchmark task sets.
//!
//! Each task lives in its own module with a `SPEC` (model file, bounds, randomisation ranges,
//! copied from the task's Python constructor) and a `build` function.

use super::{Scene, Task};
use crate::error::{Result, SimError};

mod assembly;
mod basketball;
mod bin_picking;
mod box_close;
mod button_press;
mod button_press_topdown;
mod button_press_topdown_wall;
mod button_press_wall;
mod coffee_button;
mod coffee_pull;
mod coffee_push;
mod dial_turn;
mod disassemble;
mod door_close;
mod door_lock;
mod door_open;
mod door_unlock;
mod drawer_close;
mod drawer_open;
mod faucet_close;
mod faucet_open;
mod hammer;
mod hand_insert;
mod handle_press;
mod handle_press_side;
mod handle_pull;
mod handle_pull_side;
mod lever_pull;
mod pad_caging;
mod peg_insert_side;
mod peg_unplug_side;
mod pick_out_of_hole;
mod pick_place;
mod pick_place_wall;
mod plate_slide;
mod plate_slide_back;
mod plate_slide_back_side;
mod plate_slide_side;
mod puck;
mod push;
mod push_back;
mod push_wall;
mod reach;
mod reach_wall;
mod shelf_place;
mod soccer;
mod stick_pull;
mod stick_push;
mod sweep;
mod sweep_into;
mod window_close;
mod window_open;

/// Static description of a task, mirroring the constants in its Python constructor.
#[derive(Debug)]
pub struct TaskSpec {
    /// Meta-World v3 name, e.g. `"reach-v3"`.
    pub name: &'static str,
    /// Model file relative to the Meta-World assets folder.
    pub xml: &'static str,
    /// `hand_low` / `hand_high`: also the mocap bounds unless `mocap_*` are given.
    pub hand_low: [f64; 3],
    /// Upper hand bound (see `hand_low`).
    pub hand_high: [f64; 3],
    /// Lower mocap bound when it differs from `hand_low` (`mocap_low`).
    pub mocap_low: Option<[f64; 3]>,
    /// Upper mocap bound when it differs from `hand_high` (`mocap_high`).
    pub mocap_high: Option<[f64; 3]>,
    /// Where `_reset_hand` drives the hand.
    pub hand_init_pos: [f64; 3],
    /// `_random_reset_space`: bounds of `rand_vec`.
    pub rand_low: &'static [f64],
    /// Upper bounds of `rand_vec` (see `rand_low`).
    pub rand_high: &'static [f64],
    /// `goal_space`: the goal part of the observation is clipped to it.
    pub goal_low: [f64; 3],
    /// Upper goal bound (see `goal_low`).
    pub goal_high: [f64; 3],
    /// The reset's rejection rule on `rand_vec` (Python re-draws while it fails).
    pub rand_vec_ok: fn(&[f64]) -> bool,
}

impl TaskSpec {
    /// The mocap box's lower corner: `mocap_low` if given, else `hand_low`.
    pub fn mocap_low(&self) -> [f64; 3] {
        self.mocap_low.unwrap_or(self.hand_low)
    }
    /// The mocap box's upper corner: `mocap_high` if given, else `hand_high`.
    pub fn mocap_high(&self) -> [f64; 3] {
        self.mocap_high.unwrap_or(self.hand_high)
    }
}

/// Any `rand_vec` is accepted.
pub fn always_ok(_: &[f64]) -> bool {
    true
}

/// Object (rand_vec[0..2]) and goal (rand_vec[3..5]) at least `d` apart in the plane.
pub fn obj_goal_apart<const CM: u32>(rv: &[f64]) -> bool {
    let (dx, dy) = (rv[0] - rv[3], rv[1] - rv[4]);
    (dx * dx + dy * dy).sqrt() >= f64::from(CM) / 100.0
}

/// How to build one task.
#[derive(Debug, Clone, Copy)]
pub struct Constructor {
    /// The task's static description.
    pub spec: &'static TaskSpec,
    /// Builds the task's behaviour on a freshly made scene of its model.
    pub build: fn(&Scene) -> Result<Box<dyn Task>>,
}

macro_rules! registry {
    ($($module:ident),* $(,)?) => {
        &[$(Constructor { spec: &$module::SPEC, build: $module::build }),*]
    };
}

/// Every Meta-World v3 task, in Meta-World's order (`ALL_V3_ENVIRONMENTS`, which is also MT50's).
static REGISTRY: &[Constructor] = registry![
    assembly,
    basketball,
    bin_picking,
    box_close,
    button_press_topdown,
    button_press_topdown_wall,
    button_press,
    button_press_wall,
    coffee_button,
    coffee_pull,
    coffee_push,
    dial_turn,
    disassemble,
    door_close,
    door_lock,
    door_open,
    door_unlock,
    hand_insert,
    drawer_close,
    drawer_open,
    faucet_open,
    faucet_close,
    hammer,
    handle_press_side,
    handle_press,
    handle_pull_side,
    handle_pull,
    lever_pull,
    pick_place_wall,
    pick_out_of_hole,
    pick_place,
    plate_slide,
    plate_slide_side,
    plate_slide_back,
    plate_slide_back_side,
    peg_insert_side,
    peg_unplug_side,
    soccer,
    stick_push,
    stick_pull,
    push,
    push_wall,
    push_back,
    reach,
    reach_wall,
    shelf_place,
    sweep_into,
    sweep,
    window_open,
    window_close,
];

/// Names of all implemented tasks.
pub fn task_names() -> Vec<&'static str> {
    REGISTRY.iter().map(|c| c.spec.name).collect()
}

/// The constructor of a task by name (`"reach-v3"`; `"reach"` is accepted too).
pub fn constructor(name: &str) -> Result<Constructor> {
    let full = if name.ends_with("-v3") {
        name.to_string()
    } else {
        format!("{name}-v3")
    };
    REGISTRY
        .iter()
        .find(|c| c.spec.name == full)
        .copied()
        .ok_or_else(|| SimError::UnknownTask {
            name: name.to_string(),
            valid: task_names().join(", "),
        })
}

/// Meta-World's MT10 (`MT10_V3`).
const MT10: &[&str] = &[
    "reach-v3",
    "push-v3",
    "pick-place-v3",
    "door-open-v3",
    "drawer-open-v3",
    "drawer-close-v3",
    "button-press-topdown-v3",
    "peg-insert-side-v3",
    "window-open-v3",
    "window-close-v3",
];
/// The paper's MT20: MT10 followed by these ten tasks. Not a Meta-World benchmark (Meta-World
/// 3.1.1 defines MT10, MT25 and MT50); the TERL paper chose it.
const MT20_EXTRA: &[&str] = &[
    "door-close-v3",
    "door-lock-v3",
    "door-unlock-v3",
    "button-press-v3",
    "coffee-button-v3",
    "dial-turn-v3",
    "faucet-open-v3",
    "faucet-close-v3",
    "handle-press-v3",
    "plate-slide-v3",
];
/// Meta-World's ML10 meta-training tasks (`ML10_V3["train"]`).
const ML10_TRAIN: &[&str] = &[
    "reach-v3",
    "push-v3",
    "pick-place-v3",
    "door-open-v3",
    "drawer-close-v3",
    "button-press-topdown-v3",
    "peg-insert-side-v3",
    "window-open-v3",
    "sweep-v3",
    "basketball-v3",
];
/// Meta-World's ML10 meta-test tasks (`ML10_V3["test"]`).
const ML10_TEST: &[&str] = &[
    "drawer-open-v3",
    "door-close-v3",
    "shelf-place-v3",
    "sweep-into-v3",
    "lever-pull-v3",
];
/// Meta-World's ML45 meta-training tasks (`ML45_V3["train"]`).
const ML45_TRAIN: &[&str] = &[
    "assembly-v3",
    "basketball-v3",
    "button-press-topdown-v3",
    "button-press-topdown-wall-v3",
    "button-press-v3",
    "button-press-wall-v3",
    "coffee-button-v3",
    "coffee-pull-v3",
    "coffee-push-v3",
    "dial-turn-v3",
    "disassemble-v3",
    "door-close-v3",
    "door-open-v3",
    "drawer-close-v3",
    "drawer-open-v3",
    "faucet-open-v3",
    "faucet-close-v3",
    "hammer-v3",
    "handle-press-side-v3",
    "handle-press-v3",
    "handle-pull-side-v3",
    "handle-pull-v3",
    "lever-pull-v3",
    "pick-place-wall-v3",
    "pick-out-of-hole-v3",
    "push-back-v3",
    "pick-place-v3",
    "plate-slide-v3",
    "plate-slide-side-v3",
    "plate-slide-back-v3",
    "plate-slide-back-side-v3",
    "peg-insert-side-v3",
    "peg-unplug-side-v3",
    "soccer-v3",
    "stick-push-v3",
    "stick-pull-v3",
    "push-wall-v3",
    "push-v3",
    "reach-wall-v3",
    "reach-v3",
    "shelf-place-v3",
    "sweep-into-v3",
    "sweep-v3",
    "window-open-v3",
    "window-close-v3",
];
/// Meta-World's ML45 meta-test tasks (`ML45_V3["test"]`).
const ML45_TEST: &[&str] = &[
    "bin-picking-v3",
    "box-close-v3",
    "hand-insert-v3",
    "door-lock-v3",
    "door-unlock-v3",
];
/// The paper's MT1-Ind: each task trained alone.
const MT1_IND: &[&str] = &[
    "door-open-v3",
    "button-press-v3",
    "pick-place-v3",
    "window-open-v3",
    "sweep-into-v3",
];
/// The paper's MT-Test: zero-shot evaluation of an MT10 policy.
const MT_TEST: &[&str] = &[
    "door-close-v3",
    "sweep-into-v3",
    "shelf-place-v3",
    "lever-pull-v3",
];

/// Names of the task sets, Meta-World's benchmarks first, each as Meta-World 3.1.1 defines it
/// (`metaworld/env_dict.py`):
/// - `mt10`, `mt50` (all 50 tasks, in Meta-World's order);
/// - `ml10-train`/`ml10-test` and `ml45-train`/`ml45-test`: the meta-learning benchmarks'
///   training and held-out tasks (trained here as multi-task sets, or evaluated zero-shot);
///
/// then the paper's:
/// - `mt20`: MT10 and ten more tasks, the paper's choice (not a Meta-World benchmark);
/// - `mt1-ind`: five tasks, each trained alone;
/// - `mt-test`: four tasks for zero-shot evaluation of an MT10 policy.
pub fn task_set_names() -> &'static [&'static str] {
    &[
        "mt10",
        "mt50",
        "ml10-train",
        "ml10-test",
        "ml45-train",
        "ml45-test",
        "mt20",
        "mt1-ind",
        "mt-test",
    ]
}

/// Tasks of a set (see [`task_set_names`]; `_` works for `-`, case does not matter), or a
/// single task name as a one-task set.
pub fn task_set(name: &str) -> Result<Vec<&'static str>> {
    let lower = name.to_ascii_lowercase().replace('_', "-");
    let set: Vec<&'static str> = match lower.as_str() {
        "mt10" => MT10.to_vec(),
        "mt50" => task_names(),
        "ml10-train" => ML10_TRAIN.to_vec(),
        "ml10-test" => ML10_TEST.to_vec(),
        "ml45-train" => ML45_TRAIN.to_vec(),
        "ml45-test" => ML45_TEST.to_vec(),
        "mt20" => MT10.iter().chain(MT20_EXTRA).copied().collect(),
        "mt1-ind" => MT1_IND.to_vec(),
        "mt-test" => MT_TEST.to_vec(),
        _ => {
            return constructor(name).map(|c| vec![c.spec.name]).map_err(|_| {
                SimError::UnknownTaskSet {
                    name: name.to_string(),
                    valid: format!("{} or a task name", task_set_names().join(", ")),
                }
            })
        }
    };
    Ok(set)
}
