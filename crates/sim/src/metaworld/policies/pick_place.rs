//! `SawyerPickPlaceV3Policy`: above the puck, down, close the gripper, carry to the goal.

use super::{act, add, dist, goal, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let (hand, puck) = (hand(obs), object(obs));
    let grab = if dist(hand, puck) < 0.07 { 1.0 } else { 0.0 };
    act(hand, desired_pos(hand, obs[3], puck, goal(obs)), 10.0, grab)
}

fn desired_pos(hand: V3, gripper_separation: f64, puck: V3, goal: V3) -> V3 {
    let puck = add(puck, [-0.005, 0.0, 0.0]);
    if xy_dist(hand, puck) > 0.02 {
        add(puck, [0.0, 0.0, 0.1])
    } else if (hand[2] - puck[2]).abs() > 0.05 && puck[2] < 0.04 {
        add(puck, [0.0, 0.0, 0.03])
    } else if gripper_separation > 0.73 {
        // Wait for the gripper to close.
        hand
    } else {
        goal
    }
}
