//! `SawyerShelfPlaceV3Policy`: grasp the block, centre on the shelf's x, lift, move forward.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let (hand, block) = (hand(obs), object(obs));
    act(
        hand,
        desired_pos(hand, block, obs[36]),
        25.0,
        grab_effort(hand, block),
    )
}

fn desired_pos(hand: V3, block: V3, shelf_x: f64) -> V3 {
    let block = add(block, [-0.005, 0.0, 0.015]);
    if xy_dist(hand, block) > 0.04 {
        add(block, [0.0, 0.0, 0.3])
    } else if (hand[2] - block[2]).abs() > 0.04 {
        block
    } else if (hand[0] - shelf_x).abs() > 0.02 {
        [shelf_x, hand[1], 0.3]
    } else if hand[2] < 0.30 {
        add(hand, [0.0, 0.0, 0.30])
    } else {
        add(hand, [0.0, 0.05, 0.0])
    }
}

fn grab_effort(hand: V3, block: V3) -> f64 {
    grab_near(hand, block, 0.04, 0.15, -1.0, 0.7)
}
