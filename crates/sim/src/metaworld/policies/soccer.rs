//! `SawyerSoccerV3Policy`: get behind the ball (as seen from the goal) and push it in.

use super::{act, add, goal, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs), goal(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, ball: V3, goal: V3) -> V3 {
    let ball = add(ball, [0.0, 0.0, 0.03]);
    let desired_z = if xy_dist(hand, ball) < 0.02 {
        0.1
    } else {
        0.03
    };
    const OFFSET: f64 = 0.03;
    let mut push_location = if ball[0] - goal[0] < -0.05 {
        add(ball, [-OFFSET, 0.0, 0.0])
    } else if ball[0] - goal[0] > 0.05 {
        add(ball, [OFFSET, 0.0, 0.0])
    } else {
        add(ball, [0.0, -OFFSET, 0.0])
    };
    push_location[2] = desired_z;
    if super::dist(hand, push_location) > 0.01 {
        push_location
    } else {
        ball
    }
}
