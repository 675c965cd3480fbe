//! The task registry: every implemented Meta-World v3 task and the benchmark task sets.
//!
//! Each task lives in its own module with a `SPEC` (model file, bounds, randomisation ranges,
//! copied from the task's Python constructor) and a `build` function.

use super::{Scene, Task};
use crate::error::{Result, SimError};

mod button_press;
mod button_press_topdown;
mod coffee_button;
mod dial_turn;
mod door_close;
mod door_lock;
mod door_open;
mod door_unlock;
mod drawer_close;
mod drawer_open;
mod faucet_close;
mod faucet_open;
mod handle_press;
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

// MT50 tasks, part A.
mod assembly;
mod basketball;
mod bin_picking;
mod box_close;
mod button_press_topdown_wall;
mod button_press_wall;
mod coffee_pull;
mod coffee_push;
mod disassemble;
mod hammer;
mod hand_insert;
mod handle_press_side;
mod handle_pull;
mod handle_pull_side;

/// Static description of a task, mirroring the constants in its Python constructor.
#[derive(Debug)]
pub struct TaskSpec {
    /// Meta-World v3 name, e.g. `"reach-v3"`.
    pub name: &'static str,
    /// Model file relative to the Meta-World assets folder.
    pub xml: &'static str,
    /// `hand_low` / `hand_high`: also the mocap bounds unless `mocap_*` are given.
    pub hand_low: [f64; 3],
    pub hand_high: [f64; 3],
    pub mocap_low: Option<[f64; 3]>,
    pub mocap_high: Option<[f64; 3]>,
    /// Where `_reset_hand` drives the hand.
    pub hand_init_pos: [f64; 3],
    /// `_random_reset_space`: bounds of `rand_vec`.
    pub rand_low: &'static [f64],
    pub rand_high: &'static [f64],
    /// `goal_space`: the goal part of the observation is clipped to it.
    pub goal_low: [f64; 3],
    pub goal_high: [f64; 3],
    /// The reset's rejection rule on `rand_vec` (Python re-draws while it fails).
    pub rand_vec_ok: fn(&[f64]) -> bool,
}

impl TaskSpec {
    pub fn mocap_low(&self) -> [f64; 3] {
        self.mocap_low.unwrap_or(self.hand_low)
    }
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
    pub spec: &'static TaskSpec,
    pub build: fn(&Scene) -> Result<Box<dyn Task>>,
}

macro_rules! registry {
    ($($module:ident),* $(,)?) => {
        &[$(Constructor { spec: &$module::SPEC, build: $module::build }),*]
    };
}

static REGISTRY: &[Constructor] = registry![
    reach,
    push,
    pick_place,
    door_open,
    drawer_open,
    drawer_close,
    button_press_topdown,
    peg_insert_side,
    window_open,
    window_close,
    door_close,
    door_lock,
    door_unlock,
    button_press,
    coffee_button,
    dial_turn,
    faucet_open,
    faucet_close,
    handle_press,
    plate_slide,
    sweep_into,
    shelf_place,
    lever_pull,
    // MT50 tasks, part A.
    assembly,
    basketball,
    bin_picking,
    box_close,
    button_press_topdown_wall,
    button_press_wall,
    coffee_pull,
    coffee_push,
    disassemble,
    hammer,
    hand_insert,
    handle_press_side,
    handle_pull,
    handle_pull_side,
    peg_unplug_side,
    pick_out_of_hole,
    pick_place_wall,
    plate_slide_back,
    plate_slide_back_side,
    plate_slide_side,
    push_back,
    push_wall,
    reach_wall,
    soccer,
    stick_pull,
    stick_push,
    sweep,
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
const MT1_IND: &[&str] = &[
    "door-open-v3",
    "button-press-v3",
    "pick-place-v3",
    "window-open-v3",
    "sweep-into-v3",
];
const MT_TEST: &[&str] = &[
    "door-close-v3",
    "sweep-into-v3",
    "shelf-place-v3",
    "lever-pull-v3",
];

/// Task sets of the paper: `mt1-ind` (each task trained alone), `mt10`, `mt20`, `mt-test`
/// (zero-shot evaluation).
pub fn task_set_names() -> &'static [&'static str] {
    &["mt1-ind", "mt10", "mt20", "mt-test"]
}

/// Tasks of a set, or a single task name as a one-task set.
pub fn task_set(name: &str) -> Result<Vec<&'static str>> {
    let lower = name.to_ascii_lowercase();
    let set: Vec<&'static str> = match lower.as_str() {
        "mt1-ind" | "mt1_ind" => MT1_IND.to_vec(),
        "mt10" => MT10.to_vec(),
        "mt20" => MT10.iter().chain(MT20_EXTRA).copied().collect(),
        "mt-test" | "mt_test" => MT_TEST.to_vec(),
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
