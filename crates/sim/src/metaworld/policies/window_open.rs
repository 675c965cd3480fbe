//! `SawyerWindowOpenV3Policy`: beside the handle, down, slide it along +x.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, window: V3) -> V3 {
    let window = add(window, [-0.03, -0.03, -0.08]);
    if xy_dist(hand, window) > 0.04 {
        add(window, [0.0, 0.0, 0.3])
    } else if (hand[2] - window[2]).abs() > 0.02 {
        window
    } else {
        add(window, [0.1, 0.0, 0.0])
    }
}
