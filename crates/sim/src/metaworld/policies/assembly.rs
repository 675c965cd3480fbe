//! `SawyerAssemblyV3Policy`: above the nut's handle, down, grip, up to the peg's height,
//! over the peg, then down onto it.

use super::{act, add, goal, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let wrench = add(object(obs), [-0.02, 0.0, 0.0]);
    let peg = add(goal(obs), [0.12, 0.0, 0.14]);
    act(
        hand,
        desired_pos(hand, wrench, peg),
        10.0,
        grab_effort(hand, wrench),
    )
}

fn desired_pos(hand: V3, wrench: V3, peg: V3) -> V3 {
    if xy_dist(hand, wrench) > 0.02 {
        add(wrench, [0.0, 0.0, 0.1])
    } else if xy_dist(hand, peg) <= 0.02 {
        add(peg, [0.0, 0.0, -0.2])
    } else if (hand[2] - wrench[2]).abs() > 0.05 {
        add(wrench, [0.0, 0.0, 0.03])
    } else if (hand[2] - peg[2]).abs() > 0.04 {
        [hand[0], hand[1], peg[2]]
    } else {
        peg
    }
}

fn grab_effort(hand: V3, wrench: V3) -> f64 {
    grab_near(hand, wrench, 0.02, 0.12, 0.0, 0.6)
}
