//! `SawyerDoorCloseV3Policy`: rise, come over the handle's outer edge, drop, push to the goal.

use super::{act, add, goal, hand, object, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs), goal(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, door: V3, goal: V3) -> V3 {
    let door = add(door, [0.05, 0.12, 0.1]);
    if hand[0] > door[0] {
        if hand[2] < door[2] + 0.2 {
            [hand[0], hand[1], door[2] + 0.25]
        } else {
            [door[0] - 0.02, door[1], hand[2]]
        }
    } else if (hand[2] - door[2]).abs() > 0.04 {
        add(door, [-0.02, 0.0, 0.0])
    } else {
        goal
    }
}
