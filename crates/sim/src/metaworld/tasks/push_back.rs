//! push-back-v3 (`metaworld/envs/sawyer_push_back_v3.py`): push a puck from the back of the table
//! towards the robot, to a goal on the
//! table surface.

use super::pad_caging::PadCaging;
use super::puck::{self, Variant};
use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "push-back-v3",
    xml: "sawyer_xyz/sawyer_push_back_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // Python declares it as float32.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.8, 0.02, -0.1, 0.6, 0.0199],
    rand_high: &[0.1, 0.85, 0.02, 0.1, 0.7, 0.0201],
    goal_low: [-0.1, 0.6, 0.0199],
    goal_high: [0.1, 0.7, 0.0201],
    rand_vec_ok: obj_goal_apart::<15>,
};

const CAGING: PadCaging = PadCaging {
    obj_radius: 0.007,
    grip_extra: 0.003,
    xz_success_margin: 0.01,
};
/// Success: the puck within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

const VARIANT: Variant = Variant {
    observe_body: false,
    // The puck geom's resting height after the hand reset is both the object and the goal
    // height (Python's `adjust_initObjPos`).
    resting_height: true,
    goal_site_first: false,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &VARIANT)
}

fn evaluate(scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
    let obj = [obs[4], obs[5], obs[6]];
    let tcp_opened = obs[3];
    let tcp_to_obj = dist(obj, scene.tcp_center());
    let target_to_obj = dist(obj, scene.target_pos);
    let target_to_obj_init = dist(scene.obj_init_pos, scene.target_pos);
    let in_place = tolerance(
        target_to_obj,
        (0.0, TARGET_RADIUS),
        target_to_obj_init,
        Sigmoid::LongTail,
    );
    let object_grasped = CAGING.reward(scene, obj);
    let mut reward = hamacher_product(object_grasped, in_place);
    if tcp_to_obj < 0.01
        && 0.0 < tcp_opened
        && tcp_opened < 0.55
        && target_to_obj_init - target_to_obj > 0.01
    {
        reward += 1.0 + 5.0 * in_place;
    }
    if target_to_obj < TARGET_RADIUS {
        reward = 10.0;
    }
    Eval {
        reward,
        success: target_to_obj <= SUCCESS_RADIUS,
    }
}
