//! `SawyerHandlePullSideV3Policy`: above the handle, down to it, grip lightly and pull up.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let (hand, handle) = (hand(obs), object(obs));
    act(
        hand,
        desired_pos(hand, handle),
        25.0,
        grab_effort(hand, handle),
    )
}

fn desired_pos(hand: V3, handle: V3) -> V3 {
    if xy_dist(hand, handle) > 0.04 {
        add(handle, [0.0, 0.0, 0.1])
    } else if (hand[2] - handle[2]).abs() > 0.03 {
        handle
    } else {
        add(handle, [0.0, 0.0, 1.0])
    }
}

fn grab_effort(hand: V3, handle: V3) -> f64 {
    grab_near(hand, handle, 0.04, 0.04, 0.0, 0.6)
}
