//! `SawyerDoorOpenV3Policy`: above the handle's front edge, down, pull toward its centre.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, door: V3) -> V3 {
    let door = [door[0] - 0.05, door[1], door[2]];
    if xy_dist(hand, door) > 0.12 {
        add(door, [0.06, 0.02, 0.2])
    } else if (hand[2] - door[2]).abs() > 0.04 {
        add(door, [0.06, 0.02, 0.0])
    } else {
        door
    }
}
