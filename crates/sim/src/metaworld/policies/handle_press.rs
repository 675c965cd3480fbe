//! `SawyerHandlePressV3Policy`: above the handle, then press it down.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, -1.0)
}

fn desired_pos(hand: V3, handle: V3) -> V3 {
    let handle = add(handle, [0.0, -0.02, 0.0]);
    if xy_dist(hand, handle) > 0.02 {
        add(handle, [0.0, 0.0, 0.2])
    } else {
        add(handle, [0.0, 0.0, -0.5])
    }
}
