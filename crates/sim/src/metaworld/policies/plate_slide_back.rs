//! `SawyerPlateSlideBackV3Policy`: behind the puck, down, pull it back to y = 0.55 and then
//! along x towards the goal.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 10.0, -1.0)
}

fn desired_pos(hand: V3, puck: V3) -> V3 {
    let puck = add(puck, [0.0, -0.065, 0.025]);
    if xy_dist(hand, puck) > 0.01 {
        add(puck, [0.0, 0.0, 0.1])
    } else if (hand[2] - puck[2]).abs() > 0.04 {
        puck
    } else if hand[1] > 0.7 {
        add(hand, [0.0, -0.1, 0.0])
    } else if hand[1] > 0.6 {
        [0.15, 0.55, hand[2]]
    } else {
        [hand[0] - 0.1, 0.55, hand[2]]
    }
}
