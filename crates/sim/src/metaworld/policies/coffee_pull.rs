//! `SawyerCoffeePullV3Policy`: above the mug, down around it, grip and pull it to the goal.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 10.0, desired_pos, |hand, mug| {
        grab_effort(hand, mug, 0.7)
    })
}

fn desired_pos(hand: V3, mug: V3, goal: V3) -> V3 {
    let mug = add(mug, [-0.005, 0.0, 0.05]);
    if xy_dist(hand, mug) > 0.06 {
        add(mug, [0.0, 0.0, 0.15])
    } else if (hand[2] - mug[2]).abs() > 0.02 {
        mug
    } else {
        goal
    }
}

/// Open until the hand is around the mug, then `closed` (shared with coffee-push).
pub(super) fn grab_effort(hand: V3, mug: V3, closed: f64) -> f64 {
    let mug = add(mug, [0.01, 0.0, 0.05]);
    grab_near(hand, mug, 0.06, 0.1, -1.0, closed)
}
