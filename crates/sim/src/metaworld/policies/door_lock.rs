//! `SawyerDoorLockV3Policy`: back off and rise, come over the lock, drop, push it down.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, -1.0)
}

fn desired_pos(hand: V3, lock: V3) -> V3 {
    let lock = add(lock, [-0.02, -0.02, 0.0]);
    if xy_dist(hand, lock) > 0.02 {
        if hand[2] < 0.25 {
            return add(hand, [0.0, -0.1, 0.1]);
        }
        add(lock, [0.0, 0.0, 0.3])
    } else if (hand[2] - lock[2]).abs() > 0.02 {
        lock
    } else {
        add(lock, [-0.1, 0.0, -0.1])
    }
}
