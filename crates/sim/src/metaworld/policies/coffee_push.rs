//! `SawyerCoffeePushV3Policy`: above the mug, down around it, grip and push it to the goal
//! under the machine at a height of 0.1.

use super::coffee_pull::grab_effort;
use super::{add, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 10.0, desired_pos, |hand, mug| {
        grab_effort(hand, mug, 0.5)
    })
}

fn desired_pos(hand: V3, mug: V3, goal: V3) -> V3 {
    let mug = add(mug, [0.01, 0.0, 0.05]);
    if xy_dist(hand, mug) > 0.06 {
        add(mug, [0.0, 0.0, 0.2])
    } else if (hand[2] - mug[2]).abs() > 0.02 {
        mug
    } else {
        [goal[0], goal[1], 0.1]
    }
}
