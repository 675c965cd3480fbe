//! `SawyerButtonPressWallV3Policy`: over the wall at a height of 0.3, down in front of the
//! button, then push along +y with the gripper closed.

use super::{act, add, hand, object, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let button = add(object(obs), [0.0, 0.0, 0.04]);
    let (to, grab) = desired_pos(hand, button);
    act(hand, to, 15.0, grab)
}

/// Target position and gripper effort (open until lined up in front of the button).
fn desired_pos(hand: V3, button: V3) -> (V3, f64) {
    if (hand[0] - button[0]).abs() > 0.02 {
        ([button[0], hand[1], 0.3], 1.0)
    } else if button[1] - hand[1] > 0.09 {
        ([button[0], button[1], 0.3], 1.0)
    } else if (hand[2] - button[2]).abs() > 0.02 {
        (add(button, [0.0, -0.05, 0.0]), 1.0)
    } else {
        (add(button, [0.0, -0.02, 0.0]), -1.0)
    }
}
