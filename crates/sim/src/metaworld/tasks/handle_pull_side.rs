//! handle-pull-side-v3 (`metaworld/envs/sawyer_handle_pull_side_v3.py`): pull up a handle
//! that sticks out sideways, on the left of the table.
//!
//! handle-pull-v3's task ([`super::handle_pull`]) in its sideways layout.

use super::handle_pull::{self, Layout};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "handle-pull-side-v3",
    xml: "sawyer_xyz/sawyer_handle_press_sideways.xml",
    rand_low: &[-0.35, 0.65, 0.0],
    rand_high: &[-0.25, 0.75, 0.0],
    goal_low: [-0.5, 0.40, 0.05],
    goal_high: [0.5, 1.0, 0.5],
    ..handle_pull::SPEC
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    handle_pull::build_with(scene, &SPEC, Layout::Side)
}
