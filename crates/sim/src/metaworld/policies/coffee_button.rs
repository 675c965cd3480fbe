//! `SawyerCoffeeButtonV3Policy`: line up in x and z with the button, then push along +y.

use super::{act, add, hand, object, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 10.0, -1.0)
}

fn desired_pos(hand: V3, button: V3) -> V3 {
    let button = add(button, [0.0, 0.0, -0.07]);
    let (dx, dz) = (hand[0] - button[0], hand[2] - button[2]);
    if (dx * dx + dz * dz).sqrt() > 0.02 {
        [button[0], hand[1], button[2]]
    } else {
        add(button, [0.0, 0.2, 0.0])
    }
}
