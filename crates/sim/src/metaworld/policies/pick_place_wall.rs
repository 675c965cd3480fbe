//! `SawyerPickPlaceWallV3Policy`: above the puck, down, grab, up over the wall, then to the goal.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 10.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, puck: V3, goal: V3) -> V3 {
    let puck = add(puck, [-0.005, 0.0, 0.0]);
    let over_wall = (-0.15..=0.35).contains(&hand[0]) && (0.60..=0.80).contains(&hand[1]);
    if xy_dist(hand, puck) > 0.015 {
        add(puck, [0.0, 0.0, 0.1])
    } else if (hand[2] - puck[2]).abs() > 0.04 && puck[2] < 0.03 {
        add(puck, [0.0, 0.0, 0.03])
    } else if over_wall && hand[2] < 0.25 {
        // The wall is in the way: straight up.
        add(hand, [0.0, 0.0, 1.0])
    } else if over_wall && hand[2] < 0.35 {
        [goal[0], goal[1], hand[2]]
    } else if (hand[2] - goal[2]).abs() > 0.01 {
        [hand[0], hand[1], goal[2]]
    } else {
        goal
    }
}

fn grab_effort(hand: V3, puck: V3) -> f64 {
    grab_near(hand, puck, 0.015, 0.1, 0.0, 0.9)
}
