//! reach-wall-v3: move the gripper to a goal in the air behind a wall.
//!
//! Reset, observation, reward and success are reach-v3's ([`super::reach`]); only the model
//! and the ranges differ.

use super::{obj_goal_apart, reach, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "reach-wall-v3",
    xml: "sawyer_xyz/sawyer_reach_wall_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.05, 0.6, 0.015, -0.05, 0.85, 0.05],
    rand_high: &[0.05, 0.65, 0.015, 0.05, 0.9, 0.3],
    goal_low: [-0.05, 0.85, 0.05],
    goal_high: [0.05, 0.9, 0.3],
    rand_vec_ok: obj_goal_apart::<15>,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    reach::build_with(scene, &SPEC)
}
