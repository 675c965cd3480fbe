//! door-close-v3 (`metaworld/envs/sawyer_door_close_v3.py`): swing an open door shut by
//! pushing it.
//!
//! door-open-v3's task ([`super::door_open`]) started open, with its own reward.

use super::door_open::{self, Variant};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::reward::{dist, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "door-close-v3",
    // float32 in Python's init_config.
    hand_init_pos: [-0.5, 0.6f32 as f64, 0.2f32 as f64],
    goal_low: [0.2, 0.65, 0.1499],
    goal_high: [0.3, 0.75, 0.1501],
    ..door_open::SPEC
};

/// Goal relative to the door body.
const GOAL_OFFSET: [f64; 3] = [0.2, -0.2, 0.0];
/// Hinge angle the door starts at (open). Python's literal, not exactly -pi/2.
#[allow(clippy::approx_constant)]
const DOOR_OPEN_ANGLE: f64 = -1.5708;
/// This task's own target radius.
const RADIUS: f64 = 0.05;
const SUCCESS_DISTANCE: f64 = 0.08;

const VARIANT: Variant = Variant {
    goal_offset: GOAL_OFFSET,
    hinge_angle: DOOR_OPEN_ANGLE,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    door_open::build_with(scene, &SPEC, &VARIANT)
}

/// door-close's reward and success.
fn evaluate(scene: &Scene, _theta: f64, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
    let obj = [obs[4], obs[5], obs[6]];
    let target = scene.target_pos;
    let tcp_to_target = dist(scene.tcp_center(), target);
    let obj_to_target = dist(obj, target);

    let in_place = tolerance(
        obj_to_target,
        (0.0, RADIUS),
        dist(scene.obj_init_pos, target),
        Sigmoid::Gaussian,
    );
    let hand_margin = dist(scene.hand_init_pos, obj) + 0.1;
    let hand_in_place = tolerance(
        tcp_to_target,
        (0.0, 0.25 * RADIUS),
        hand_margin,
        Sigmoid::Gaussian,
    );
    let reward = if obj_to_target < RADIUS {
        10.0
    } else {
        3.0 * hand_in_place + 6.0 * in_place
    };
    Eval {
        reward,
        success: obj_to_target <= SUCCESS_DISTANCE,
    }
}
