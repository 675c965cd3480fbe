//! `SawyerStickPushV3Policy`: grasp the stick, line it up with the container, then move to
//! 13.2 cm above the goal (pushing the container there).

use super::{act, add, goal, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    stick_action(obs, [0.015, 0.0, 0.03], [0.0; 3], [0.0, 0.0, 0.132], 10.0)
}

/// The state machine both stick policies share; the offsets are added to the stick
/// (obs[4..7]), the container (obs[11..14]) and the goal.
pub(super) fn stick_action(
    obs: &[f64; OBS_DIM],
    stick_offset: V3,
    thermos_offset: V3,
    goal_offset: V3,
    p: f64,
) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let stick = add(object(obs), stick_offset);
    let thermos = add([obs[11], obs[12], obs[13]], thermos_offset);
    let goal = add(goal(obs), goal_offset);
    let to = if (stick[0] - thermos[0]).abs() > 0.04 {
        if xy_dist(hand, stick) > 0.02 {
            add(stick, [0.0, 0.0, 0.1])
        } else if (hand[2] - stick[2]).abs() > 0.02 {
            stick
        } else if (stick[1] - thermos[1]).abs() > 0.02 {
            [stick[0], thermos[1], stick[2]]
        } else if (stick[2] - thermos[2]).abs() > 0.02 {
            [stick[0], thermos[1], thermos[2]]
        } else {
            thermos
        }
    } else {
        goal
    };
    let grab = if xy_dist(hand, stick) > 0.02 || (hand[2] - stick[2]).abs() > 0.1 {
        -1.0
    } else {
        0.7
    };
    act(hand, to, p, grab)
}
