//! `SawyerFaucetOpenV3Policy`: above the handle's end, down, turn it along +x.

use super::{act, add, hand, object, xy_dist, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 1.0)
}

fn desired_pos(hand: V3, faucet: V3) -> V3 {
    let faucet = add(faucet, [-0.04, 0.0, 0.03]);
    if xy_dist(hand, faucet) > 0.04 {
        add(faucet, [0.0, 0.0, 0.1])
    } else if (hand[2] - faucet[2]).abs() > 0.04 {
        faucet
    } else {
        add(faucet, [0.1, 0.05, 0.0])
    }
}
