//! `SawyerLeverPullV3Policy`: under the lever's end, then lift it up and back.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, lever: V3) -> V3 {
    let lever = add(lever, [0.0, -0.055, 0.0]);
    if xy_dist(hand, lever) > 0.02 {
        add(lever, [0.0, 0.0, -0.1])
    } else if (hand[2] - lever[2]).abs() > 0.02 {
        lever
    } else {
        add(lever, [0.0, 0.08, 0.02])
    }
}
