//! reach-wall-v3 (`metaworld/envs/sawyer_reach_wall_v3.py`): move the gripper to a goal in the air
//! behind a wall.
//!
//! Reset, observation, reward and success are reach-v3's ([`super::reach`]); only the model
//! and the ranges differ.

use super::{puck, reach, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "reach-wall-v3",
    xml: "sawyer_xyz/sawyer_reach_wall_v3.xml",
    rand_low: &[-0.05, 0.6, 0.015, -0.05, 0.85, 0.05],
    rand_high: &[0.05, 0.65, 0.015, 0.05, 0.9, 0.3],
    goal_low: [-0.05, 0.85, 0.05],
    goal_high: [0.05, 0.9, 0.3],
    ..reach::SPEC
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &reach::VARIANT)
}
