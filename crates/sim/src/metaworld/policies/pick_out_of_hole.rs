//! `SawyerPickOutOfHoleV3Policy`: above the peg, down, grip lightly, up to the goal's height,
//! then to the goal.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 25.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, puck: V3, goal: V3) -> V3 {
    let puck = add(puck, [0.0, 0.0, 0.02]);
    if xy_dist(hand, puck) > 0.02 {
        add(puck, [0.0, 0.0, 0.15])
    } else if (hand[2] - puck[2]).abs() > 0.01 {
        puck
    } else if (hand[2] - goal[2]).abs() > 0.04 {
        [hand[0], hand[1], goal[2]]
    } else {
        goal
    }
}

fn grab_effort(hand: V3, puck: V3) -> f64 {
    let puck = add(puck, [0.0, 0.0, 0.02]);
    grab_near(hand, puck, 0.02, 0.15, 0.0, 0.1)
}
