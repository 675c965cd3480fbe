//! `SawyerReachWallV3Policy`: to the goal, aiming 1 m above it while the wall is in the way.

use super::{act, add, goal, hand, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, goal(obs)), 5.0, 0.0)
}

fn desired_pos(hand: V3, goal: V3) -> V3 {
    if (-0.1..=0.3).contains(&hand[0]) && (0.60..=0.80).contains(&hand[1]) && hand[2] < 0.25 {
        add(goal, [0.0, 0.0, 1.0])
    } else {
        goal
    }
}
