//! `SawyerButtonPressTopdownWallV3Policy`: above a point 6 cm in front of the button, then
//! press down with the gripper open.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, -1.0)
}

fn desired_pos(hand: V3, button: V3) -> V3 {
    let button = add(button, [0.0, -0.06, 0.0]);
    if xy_dist(hand, button) > 0.04 {
        add(button, [0.0, 0.0, 0.1])
    } else {
        button
    }
}
