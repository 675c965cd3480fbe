//! `SawyerPlateSlideBackSideV3Policy`: above the puck, down, push it towards +x at y = 0.6.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 10.0, 1.0)
}

fn desired_pos(hand: V3, puck: V3) -> V3 {
    let puck = add(puck, [0.023, 0.0, 0.025]);
    if xy_dist(hand, puck) > 0.01 {
        add(puck, [0.0, 0.0, 0.07])
    } else if (hand[2] - puck[2]).abs() > 0.04 {
        puck
    } else {
        [hand[0] + 0.1, 0.6, hand[2]]
    }
}
