//! plate-slide-back-side-v3 (`metaworld/envs/sawyer_plate_slide_back_side_v3.py`): slide a
//! puck out of the side cabinet (towards +x) into a goal.
//!
//! plate-slide-v3's task ([`super::plate_slide`]) started in the side cabinet, with the
//! low-push reward.

use super::plate_slide::{self, PuckGoal, Reward, Variant};
use super::{plate_slide_side, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "plate-slide-back-side-v3",
    rand_low: &[-0.25, 0.6, 0.0, -0.05, 0.6, 0.015],
    rand_high: &[-0.25, 0.6, 0.0, 0.15, 0.6, 0.015],
    goal_low: [-0.05, 0.6, 0.015],
    goal_high: [0.15, 0.6, 0.015],
    ..plate_slide_side::SPEC
};

const VARIANT: Variant = Variant {
    // The cabinet marker goes to the puck's start (Python writes obj_init_pos here).
    puck_goal: PuckGoal::AtStart,
    puck_joints: [-0.15, 0.0],
    reward: Reward::LowPush,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    plate_slide::build_with(scene, &SPEC, &VARIANT)
}
