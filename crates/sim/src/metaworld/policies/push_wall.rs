//! `SawyerPushWallV3Policy`: above the puck, down onto it, then push it around the wall to the
//! goal.

use super::{add, grab_near, object_to_goal, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    object_to_goal(obs, 10.0, desired_pos, grab_effort)
}

fn desired_pos(hand: V3, obj: V3, goal: V3) -> V3 {
    let obj = add(obj, [-0.005, 0.0, 0.0]);
    if xy_dist(hand, obj) > 0.02 {
        add(obj, [0.0, 0.0, 0.2])
    } else if (hand[2] - obj[2]).abs() > 0.04 {
        add(obj, [0.0, 0.0, 0.03])
    } else if (-0.1..=0.3).contains(&obj[0]) && (0.65..=0.75).contains(&obj[1]) {
        // The wall is between the puck and the goal: go around it.
        add(hand, [-1.0, 0.0, 0.0])
    } else if ((-0.15 < obj[0] && obj[0] < 0.05) || (0.15 < obj[0] && obj[0] < 0.35))
        && (0.695..=0.755).contains(&obj[1])
    {
        add(hand, [0.0, 1.0, 0.0])
    } else {
        goal
    }
}

fn grab_effort(hand: V3, obj: V3) -> f64 {
    grab_near(hand, obj, 0.02, 0.1, 0.0, 0.6)
}
