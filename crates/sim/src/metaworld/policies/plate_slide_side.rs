//! `SawyerPlateSlideSideV3Policy`: beside the puck (+x), down, push it towards -x at y = 0.6.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, puck: V3) -> V3 {
    let puck = add(puck, [0.07, 0.0, -0.005]);
    if xy_dist(hand, puck) > 0.04 {
        add(puck, [0.0, 0.0, 0.1])
    } else if (hand[2] - puck[2]).abs() > 0.04 {
        puck
    } else if hand[0] > -0.2 {
        [hand[0] - 0.1, 0.6, hand[2]]
    } else {
        add(puck, [-0.1, 0.0, 0.0])
    }
}
