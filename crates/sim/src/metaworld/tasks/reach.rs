//! reach-v3 (`metaworld/envs/sawyer_reach_v3.py`): move the gripper to a goal in the air.

use super::puck::{self, Variant};
use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "reach-v3",
    xml: "sawyer_xyz/sawyer_reach_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.6, 0.02, -0.1, 0.8, 0.05],
    rand_high: &[0.1, 0.7, 0.02, 0.1, 0.9, 0.3],
    goal_low: [-0.1, 0.8, 0.05],
    goal_high: [0.1, 0.9, 0.3],
    rand_vec_ok: obj_goal_apart::<15>,
};

/// reach-v3's variant of the puck tasks (reach-wall-v3 has the same).
pub(super) const VARIANT: Variant = Variant {
    observe_body: true,
    resting_height: false,
    goal_site_first: false,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &VARIANT)
}

/// The reward and success of reach-v3 and reach-wall-v3.
fn evaluate(scene: &Scene, _obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
    let tcp_to_target = dist(scene.tcp_center(), scene.target_pos);
    let in_place_margin = dist(scene.hand_init_pos, scene.target_pos);
    let in_place = tolerance(
        tcp_to_target,
        (0.0, TARGET_RADIUS),
        in_place_margin,
        Sigmoid::LongTail,
    );
    Eval {
        reward: 10.0 * in_place,
        success: tcp_to_target <= 0.05,
    }
}
