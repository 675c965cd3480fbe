//! coffee-push-v3 (`metaworld/envs/sawyer_coffee_push_v3.py`): push a mug under a coffee
//! machine.
//!
//! coffee-pull-v3's task ([`super::coffee_pull`]) with the machine behind the goal.

use super::coffee_pull::{self, Coffee};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "coffee-push-v3",
    rand_low: &[-0.1, 0.55, -0.001, -0.05, 0.7, -0.001],
    rand_high: &[0.1, 0.65, 0.001, 0.05, 0.75, 0.001],
    goal_low: [-0.05, 0.7, -0.001],
    goal_high: [0.05, 0.75, 0.001],
    ..coffee_pull::SPEC
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Coffee::new(scene, &SPEC, true)?))
}
