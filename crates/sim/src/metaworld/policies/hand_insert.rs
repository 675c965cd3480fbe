//! `SawyerHandInsertV3Policy`: above the block, down onto it, grip, over the hole, then down.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 10.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, obj: V3, goal: V3) -> V3 {
    if xy_dist(hand, obj) > 0.02 {
        add(obj, [0.0, 0.0, 0.1])
    } else if (hand[2] - obj[2]).abs() > 0.05 {
        add(obj, [0.0, 0.0, 0.03])
    } else if xy_dist(hand, goal) > 0.04 {
        [goal[0], goal[1], hand[2]]
    } else {
        goal
    }
}

fn grab_effort(hand: V3, obj: V3) -> f64 {
    grab_near(hand, obj, 0.02, 0.1, 0.0, 0.65)
}
