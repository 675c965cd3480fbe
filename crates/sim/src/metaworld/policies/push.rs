//! `SawyerPushV3Policy`: above the puck, down onto it, then push (half-gripped) to the goal.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 10.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, puck: V3, goal: V3) -> V3 {
    let puck = add(puck, [-0.005, 0.0, 0.0]);
    if xy_dist(hand, puck) > 0.02 {
        add(puck, [0.0, 0.0, 0.2])
    } else if (hand[2] - puck[2]).abs() > 0.04 {
        add(puck, [0.0, 0.0, 0.03])
    } else {
        goal
    }
}

fn grab_effort(hand: V3, puck: V3) -> f64 {
    grab_near(hand, puck, 0.02, 0.10, 0.0, 0.6)
}
