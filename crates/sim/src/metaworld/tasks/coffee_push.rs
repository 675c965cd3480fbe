//! coffee-push-v3: push a mug under a coffee machine.

use super::coffee_pull::Coffee;
use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "coffee-push-v3",
    xml: "sawyer_xyz/sawyer_coffee.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.4, 0.2],
    rand_low: &[-0.1, 0.55, -0.001, -0.05, 0.7, -0.001],
    rand_high: &[0.1, 0.65, 0.001, 0.05, 0.75, 0.001],
    goal_low: [-0.05, 0.7, -0.001],
    goal_high: [0.05, 0.75, 0.001],
    rand_vec_ok: obj_goal_apart::<15>,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(Coffee::new(scene, &SPEC, true)?))
}
