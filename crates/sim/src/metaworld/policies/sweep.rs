//! `SawyerSweepV3Policy`: down onto the block, grip it and sweep it to 10 cm above the goal.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 25.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, cube: V3, goal: V3) -> V3 {
    let cube = add(cube, [0.0, 0.0, 0.015]);
    if hand[0] < 0.2 {
        if xy_dist(hand, cube) > 0.04 {
            return add(cube, [0.0, 0.0, 0.3]);
        } else if (hand[2] - cube[2]).abs() > 0.04 {
            return cube;
        }
    }
    add(goal, [0.0, 0.0, 0.1])
}

fn grab_effort(hand: V3, cube: V3) -> f64 {
    let near = if cube[0] < 0.4 { 0.7 } else { -1.0 };
    grab_near(hand, cube, 0.04, 0.15, -1.0, near)
}
