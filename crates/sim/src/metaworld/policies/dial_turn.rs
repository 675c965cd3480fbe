//! `SawyerDialTurnV3Policy`: above the dial's edge, down, sweep it along -x.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 10.0, 1.0)
}

fn desired_pos(hand: V3, dial: V3) -> V3 {
    let dial = add(dial, [0.05, 0.02, 0.09]);
    if xy_dist(hand, dial) > 0.02 {
        [dial[0], dial[1], 0.2]
    } else if (hand[2] - dial[2]).abs() > 0.02 {
        dial
    } else {
        add(dial, [-0.05, 0.005, 0.0])
    }
}
