//! `SawyerHammerV3Policy`: above the handle, down, grip, to the nail's height and x, then
//! forward onto the nail.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

/// The nail head (plus an offset for the hammer's head), hard-coded as in Python.
const GOAL: V3 = [0.24 - 0.19, 0.71, 0.11 + 0.05];

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let handle = add(object(obs), [-0.04, 0.0, -0.01]);
    act(
        hand,
        desired_pos(hand, handle),
        10.0,
        grab_effort(hand, handle),
    )
}

fn desired_pos(hand: V3, handle: V3) -> V3 {
    let xz_dist = ((hand[0] - GOAL[0]).powi(2) + (hand[2] - GOAL[2]).powi(2)).sqrt();
    if xy_dist(hand, handle) > 0.04 {
        add(handle, [0.0, 0.0, 0.1])
    } else if (hand[2] - handle[2]).abs() > 0.05 && handle[2] < 0.03 {
        add(handle, [0.0, 0.0, 0.03])
    } else if xz_dist > 0.02 {
        [GOAL[0], hand[1], GOAL[2]]
    } else {
        GOAL
    }
}

fn grab_effort(hand: V3, handle: V3) -> f64 {
    grab_near(hand, handle, 0.04, 0.1, 0.0, 0.8)
}
