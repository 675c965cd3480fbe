//! `SawyerDrawerCloseV3Policy`: rise, move in front of the handle, drop, push it in.

use super::{act, add, hand, object, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, drawer: V3) -> V3 {
    let drawer = add(drawer, [0.0, 0.0, -0.02]);
    if hand[1] > drawer[1] {
        if hand[2] < drawer[2] + 0.23 {
            [hand[0], hand[1], drawer[2] + 0.5]
        } else {
            add(drawer, [0.0, -0.075, 0.23])
        }
    } else if (hand[2] - drawer[2]).abs() > 0.04 {
        add(drawer, [0.0, -0.075, 0.0])
    } else {
        drawer
    }
}
