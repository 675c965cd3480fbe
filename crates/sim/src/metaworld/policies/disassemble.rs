//! `SawyerDisassembleV3Policy`: above the nut's handle, down, grip, then straight up.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let wrench = add(object(obs), [-0.02, 0.0, 0.01]);
    act(
        hand,
        desired_pos(hand, wrench),
        10.0,
        grab_effort(hand, wrench),
    )
}

fn desired_pos(hand: V3, wrench: V3) -> V3 {
    if xy_dist(hand, wrench) > 0.02 {
        add(wrench, [0.0, 0.0, 0.1])
    } else if (hand[2] - wrench[2]).abs() > 0.03 {
        wrench
    } else {
        add(hand, [0.0, 0.0, 0.1])
    }
}

fn grab_effort(hand: V3, wrench: V3) -> f64 {
    grab_near(hand, wrench, 0.02, 0.07, 0.0, 0.8)
}
