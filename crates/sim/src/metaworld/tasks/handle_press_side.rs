//! handle-press-side-v3 (`metaworld/envs/sawyer_handle_press_side_v3.py`): press down a
//! handle that sticks out sideways, on the left of the table.
//!
//! Reset, observation, reward and success are handle-press-v3's ([`super::handle_press`]);
//! only the model and the ranges differ.

use super::{handle_press, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "handle-press-side-v3",
    xml: "sawyer_xyz/sawyer_handle_press_sideways.xml",
    rand_low: &[-0.35, 0.65, -0.001],
    rand_high: &[-0.25, 0.75, 0.001],
    goal_low: [-0.5, 0.40, 0.05],
    goal_high: [0.5, 1.0, 0.5],
    ..handle_press::SPEC
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    handle_press::build_with(scene, &SPEC)
}
