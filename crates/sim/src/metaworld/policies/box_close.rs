//! `SawyerBoxCloseV3Policy`: above the lid's handle, down, grip, up to 0.15, over the box.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let lid = add(object(obs), [0.0, 0.0, 0.02]);
    let box_top = [obs[36], obs[37], 0.15];
    act(
        hand,
        desired_pos(hand, lid, box_top),
        25.0,
        grab_effort(hand, lid),
    )
}

fn desired_pos(hand: V3, lid: V3, box_top: V3) -> V3 {
    if xy_dist(hand, lid) > 0.01 {
        [lid[0], lid[1], 0.2]
    } else if (hand[2] - lid[2]).abs() > 0.05 {
        lid
    } else if (hand[2] - box_top[2]).abs() > 0.04 {
        [hand[0], hand[1], box_top[2]]
    } else {
        box_top
    }
}

fn grab_effort(hand: V3, lid: V3) -> f64 {
    grab_near(hand, lid, 0.01, 0.13, 0.5, 1.0)
}
