//! push-wall-v3 (`metaworld/envs/sawyer_push_wall_v3.py`): push a puck around a wall to a goal on
//! the table surface.

use super::pick_place_wall::{wall_evaluate, Wall};
use super::puck::{self, Variant};
use super::{reach, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "push-wall-v3",
    xml: "sawyer_xyz/sawyer_push_wall_v3.xml",
    rand_low: &[-0.05, 0.6, 0.015, -0.05, 0.85, 0.01],
    rand_high: &[0.05, 0.65, 0.015, 0.05, 0.9, 0.02],
    goal_low: [-0.05, 0.85, 0.01],
    goal_high: [0.05, 0.9, 0.02],
    ..reach::SPEC
};

const VARIANT: Variant = Variant {
    observe_body: false,
    // The puck geom's resting height after the hand reset is both the object and the goal
    // height (Python's `adjust_initObjPos`).
    resting_height: true,
    goal_site_first: true,
    evaluate,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    puck::build_with(scene, &SPEC, &VARIANT)
}

/// The reward is pick-place-wall's ([`wall_evaluate`]) with a waypoint at the puck's height
/// and the x distance to it weighted three times.
const WALL: Wall = Wall {
    midpoint: |_, obj| [-0.05, 0.77, obj[2]],
    scaling: [3.0, 1.0, 1.0],
    density: Density::High,
    pick: false,
};

fn evaluate(scene: &Scene, obs: &[f64; OBS_DIM], action: &[f32; ACTION_DIM]) -> Eval {
    wall_evaluate(scene, obs, action, &WALL)
}
