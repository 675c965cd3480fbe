//! pick-place-v3 (`metaworld/envs/sawyer_pick_place_v3.py`): pick up a puck and hold it at a goal
//! in the air.

use super::pad_caging::PadCaging;
use super::puck::{self, Variant};
use super::{reach, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "pick-place-v3",
    xml: "sawyer_xyz/sawyer_pick_place_v3.xml",
    rand_low: &[-0.1, 0.6, 0.02, -0.1, 0.8, 0.05],
    rand_high: &[0.1, 0.7, 0.02, 0.1, 0.9, 0.3],
    goal_low: [-0.1, 0.8, 0.05],
    goal_high: [0.1, 0.9, 0.3],
    ..reach::SPEC
};

/// Parameters of the task's own caging reward (its gripping term reads the action instead
/// of the pads, so `grip_extra` is unused).
const CAGING: PadCaging = PadCaging {
    obj_radius: 0.015,
    grip_extra: 0.0,
    xz_success_margin: 0.005,
};
/// Success: the puck within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

const VARIANT: Variant = Variant {
    observe_body: true,
    resting_height: false,
    goal_site_first: false,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &VARIANT)
}

/// The task's override of `_gripper_caging_reward` (high density). Its margins are measured
/// from `init_left_pad`/`init_right_pad`, which in Python are live views of `data.xpos`
/// (`get_body_com` returns no copy): they are the *current* pad positions, not the ones at
/// reset.
fn caging_reward(scene: &Scene, action: &[f32; ACTION_DIM], obj: [f64; 3]) -> f64 {
    let (caging, _) = CAGING.caging(scene, obj);
    let gripper_closed = f64::from(action[3].clamp(0.0, 1.0));
    let gripping = if caging > 0.97 { gripper_closed } else { 0.0 };
    (hamacher_product(caging, gripping) + caging) / 2.0
}

fn evaluate(scene: &Scene, obs: &[f64; OBS_DIM], action: &[f32; ACTION_DIM]) -> Eval {
    let obj = [obs[4], obs[5], obs[6]];
    let tcp_opened = obs[3];
    let target = scene.target_pos;
    let obj_to_target = dist(obj, target);
    let tcp_to_obj = dist(obj, scene.tcp_center());
    let in_place_margin = dist(scene.obj_init_pos, target);
    let in_place = tolerance(
        obj_to_target,
        (0.0, TARGET_RADIUS),
        in_place_margin,
        Sigmoid::LongTail,
    );
    let object_grasped = caging_reward(scene, action, obj);
    let mut reward = hamacher_product(object_grasped, in_place);
    if tcp_to_obj < 0.02 && tcp_opened > 0.0 && obj[2] - 0.01 > scene.obj_init_pos[2] {
        reward += 1.0 + 5.0 * in_place;
    }
    if obj_to_target < TARGET_RADIUS {
        reward = 10.0;
    }
    Eval {
        reward,
        success: obj_to_target <= SUCCESS_RADIUS,
    }
}
