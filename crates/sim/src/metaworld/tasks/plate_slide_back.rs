//! plate-slide-back-v3 (`metaworld/envs/sawyer_plate_slide_back_v3.py`): slide a puck out of
//! the cabinet, back towards the robot, into a goal.
//!
//! plate-slide-v3's task ([`super::plate_slide`]) started in the cabinet, with the low-push
//! reward.

use super::plate_slide::{self, PuckGoal, Reward, Variant};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "plate-slide-back-v3",
    rand_low: &[0.0, 0.85, 0.0, -0.1, 0.6, 0.015],
    rand_high: &[0.0, 0.85, 0.0, 0.1, 0.6, 0.015],
    goal_low: [-0.1, 0.6, 0.015],
    goal_high: [0.1, 0.6, 0.015],
    ..plate_slide::SPEC
};

const VARIANT: Variant = Variant {
    puck_goal: PuckGoal::Unmoved,
    puck_joints: [0.0, 0.15],
    reward: Reward::LowPush,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    plate_slide::build_with(scene, &SPEC, &VARIANT)
}
