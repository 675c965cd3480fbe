//! `SawyerDrawerOpenV3Policy`: above the handle, down, then pull hard (p = 50) behind it.

use super::{act, add, hand, object, xy_dist};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let drawer = add(object(obs), [0.0, 0.0, -0.02]);
    let (to, p) = if xy_dist(hand, drawer) > 0.06 {
        (add(drawer, [0.0, 0.0, 0.3]), 4.0)
    } else if (hand[2] - drawer[2]).abs() > 0.04 {
        (drawer, 4.0)
    } else {
        (add(drawer, [0.0, -0.06, 0.0]), 50.0)
    };
    act(hand, to, p, -1.0)
}
