//! `SawyerBasketballV3Policy`: above the ball, down, grip, up to the hoop's height, over it.

use super::{act, add, grab_near, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let (hand, ball) = (hand(obs), object(obs));
    // x from the goal; y between the basket's limits (0.85..0.9); z fixed.
    let hoop = [obs[36], 0.875, 0.35];
    act(
        hand,
        desired_pos(hand, ball, hoop),
        25.0,
        grab_effort(hand, ball),
    )
}

fn desired_pos(hand: V3, ball: V3, hoop: V3) -> V3 {
    let ball = add(ball, [0.0, 0.0, 0.01]);
    if xy_dist(hand, ball) > 0.04 {
        add(ball, [0.0, 0.0, 0.3])
    } else if (hand[2] - ball[2]).abs() > 0.025 {
        ball
    } else if (ball[2] - hoop[2]).abs() > 0.025 {
        [hand[0], hand[1], hoop[2]]
    } else {
        hoop
    }
}

fn grab_effort(hand: V3, ball: V3) -> f64 {
    grab_near(hand, ball, 0.04, 0.15, -1.0, 0.6)
}
