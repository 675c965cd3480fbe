//! push-v3 (`metaworld/envs/sawyer_push_v3.py`): push a puck across the table to a goal on the
//! table surface.

use super::puck::{self, Variant};
use super::{reach, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "push-v3",
    xml: "sawyer_xyz/sawyer_push_v3.xml",
    rand_low: &[-0.1, 0.6, 0.02, -0.1, 0.8, 0.01],
    rand_high: &[0.1, 0.7, 0.02, 0.1, 0.9, 0.02],
    goal_low: [-0.1, 0.8, 0.01],
    goal_high: [0.1, 0.9, 0.02],
    ..reach::SPEC
};

/// Caging reward parameters of the puck.
const OBJ_RADIUS: f64 = 0.015;
const PAD_SUCCESS_THRESH: f64 = 0.05;
const OBJECT_REACH_RADIUS: f64 = 0.01;
const XZ_THRESH: f64 = 0.005;

const VARIANT: Variant = Variant {
    observe_body: true,
    // The puck's resting height after the hand reset is both the object and the goal height.
    resting_height: true,
    goal_site_first: false,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &VARIANT)
}

fn evaluate(scene: &Scene, obs: &[f64; OBS_DIM], action: &[f32; ACTION_DIM]) -> Eval {
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
    let object_grasped = scene.gripper_caging_reward(
        action,
        obj,
        OBJ_RADIUS,
        PAD_SUCCESS_THRESH,
        OBJECT_REACH_RADIUS,
        XZ_THRESH,
        1.0,
        Density::High,
    );
    let mut reward = 2.0 * object_grasped;
    if tcp_to_obj < 0.02 && tcp_opened > 0.0 {
        reward += 1.0 + reward + 5.0 * in_place;
    }
    if target_to_obj < TARGET_RADIUS {
        reward = 10.0;
    }
    Eval {
        reward,
        success: target_to_obj <= TARGET_RADIUS,
    }
}
