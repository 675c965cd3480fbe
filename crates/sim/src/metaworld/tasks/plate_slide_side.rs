//! plate-slide-side-v3 (`metaworld/envs/sawyer_plate_slide_side_v3.py`): slide a puck
//! sideways (towards -x) into a goal beside the table centre.
//!
//! plate-slide-v3's task ([`super::plate_slide`]) on the sideways table, with the low-push
//! reward.

use super::plate_slide::{self, PuckGoal, Reward, Variant};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "plate-slide-side-v3",
    xml: "sawyer_xyz/sawyer_plate_slide_sideway.xml",
    rand_low: &[0.0, 0.6, 0.0, -0.3, 0.54, 0.0],
    rand_high: &[0.0, 0.6, 0.0, -0.25, 0.66, 0.0],
    goal_low: [-0.3, 0.54, 0.0],
    goal_high: [-0.25, 0.66, 0.0],
    ..plate_slide::SPEC
};

const VARIANT: Variant = Variant {
    puck_goal: PuckGoal::Unmoved,
    puck_joints: [0.0, 0.0],
    reward: Reward::LowPush,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    plate_slide::build_with(scene, &SPEC, &VARIANT)
}
