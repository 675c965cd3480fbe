//! pick-place-wall-v3 (`metaworld/envs/sawyer_pick_place_wall_v3.py`): pick up a puck and carry it
//! over a wall to a goal in the air.

use super::puck::{self, Variant};
use super::{reach, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, scaled_dist, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "pick-place-wall-v3",
    xml: "sawyer_xyz/sawyer_pick_place_wall_v3.xml",
    rand_low: &[-0.05, 0.6, 0.015, -0.05, 0.85, 0.05],
    rand_high: &[0.05, 0.65, 0.015, 0.05, 0.9, 0.3],
    goal_low: [-0.05, 0.85, 0.05],
    goal_high: [0.05, 0.9, 0.3],
    ..reach::SPEC
};

/// Success: the puck within this distance of the goal.
const SUCCESS_RADIUS: f64 = 0.07;

const VARIANT: Variant = Variant {
    observe_body: false,
    resting_height: false,
    goal_site_first: false,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &VARIANT)
}

/// What differs between the rewards of pick-place-wall and push-wall.
#[derive(Debug)]
pub(super) struct Wall {
    /// The waypoint beside the wall, from the goal and the puck.
    pub midpoint: fn(target: [f64; 3], obj: [f64; 3]) -> [f64; 3],
    /// Per-axis weights of the distance to the waypoint.
    pub scaling: [f64; 3],
    /// The caging reward's density option.
    pub density: Density,
    /// pick-place-wall: the base reward is `hamacher(grasped, in place part 1)` and the bonus
    /// needs the puck lifted; push-wall: the base reward is `2 × grasped`.
    pub pick: bool,
}

const WALL: Wall = Wall {
    midpoint: |target, _| [target[0], 0.77, 0.25],
    scaling: [1.0, 1.0, 3.0],
    density: Density::Normal,
    pick: true,
};

fn evaluate(scene: &Scene, obs: &[f64; OBS_DIM], action: &[f32; ACTION_DIM]) -> Eval {
    wall_evaluate(scene, obs, action, &WALL)
}

/// The reward and success of pick-place-wall and push-wall: first towards a waypoint beside
/// the wall, then (past y = 0.75) to the goal.
pub(super) fn wall_evaluate(
    scene: &Scene,
    obs: &[f64; OBS_DIM],
    action: &[f32; ACTION_DIM],
    wall: &Wall,
) -> Eval {
    let obj = [obs[4], obs[5], obs[6]];
    let tcp_opened = obs[3];
    let target = scene.target_pos;
    let midpoint = (wall.midpoint)(target, obj);
    let scaling = wall.scaling;
    let tcp_to_obj = dist(obj, scene.tcp_center());
    let obj_to_target = dist(obj, target);
    let in_place_part1 = tolerance(
        scaled_dist(obj, midpoint, scaling),
        (0.0, TARGET_RADIUS),
        scaled_dist(scene.obj_init_pos, midpoint, scaling),
        Sigmoid::LongTail,
    );
    let in_place_part2 = tolerance(
        obj_to_target,
        (0.0, TARGET_RADIUS),
        dist(scene.obj_init_pos, target),
        Sigmoid::LongTail,
    );
    let object_grasped =
        scene.gripper_caging_reward(action, obj, 0.015, 0.05, 0.01, 0.005, 1.0, wall.density);
    let base = if wall.pick {
        hamacher_product(object_grasped, in_place_part1)
    } else {
        2.0 * object_grasped
    };
    let lifted = !wall.pick || obj[2] - 0.015 > scene.obj_init_pos[2];
    let mut reward = base;
    if tcp_to_obj < 0.02 && tcp_opened > 0.0 && lifted {
        reward = base + 1.0 + 4.0 * in_place_part1;
        if obj[1] > 0.75 {
            reward = base + 1.0 + 4.0 + 3.0 * in_place_part2;
        }
    }
    if obj_to_target < TARGET_RADIUS {
        reward = 10.0;
    }
    Eval {
        reward,
        success: obj_to_target <= SUCCESS_RADIUS,
    }
}
