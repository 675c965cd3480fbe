//! `SawyerPegUnplugSideV3Policy`: above the peg, down to z = 0.15, then pull along +x.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let (hand, peg) = (hand(obs), object(obs));
    act(hand, desired_pos(hand, peg), 25.0, grab_effort(hand, peg))
}

fn desired_pos(hand: V3, peg: V3) -> V3 {
    let peg = add(peg, [-0.02, 0.0, 0.035]);
    if xy_dist(hand, peg) > 0.04 {
        add(peg, [0.0, 0.0, 0.2])
    } else if (hand[2] - 0.15).abs() > 0.02 {
        [peg[0], peg[1], 0.15]
    } else {
        add(hand, [0.01, 0.0, 0.0])
    }
}

fn grab_effort(hand: V3, peg: V3) -> f64 {
    let peg = add(peg, [-0.02, 0.0, 0.035]);
    grab_near(hand, peg, 0.04, 0.15, -1.0, 0.1)
}
