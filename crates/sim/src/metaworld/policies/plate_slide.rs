//! `SawyerPlateSlideV3Policy`: behind the plate, down, slide it to the goal's x at y = 0.9.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs), obs[36]), 10.0, -1.0)
}

fn desired_pos(hand: V3, puck: V3, goal_x: f64) -> V3 {
    let puck = add(puck, [0.0, -0.055, 0.03]);
    if xy_dist(hand, puck) > 0.03 {
        add(puck, [0.0, 0.0, 0.1])
    } else if (hand[2] - puck[2]).abs() > 0.04 {
        puck
    } else {
        [goal_x, 0.9, puck[2]]
    }
}
