//! `SawyerButtonPressV3Policy`: line up in x and z with the button, then push along +y.

use super::{act, add, hand, object, V3};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    act(hand, desired_pos(hand, object(obs)), 25.0, 0.0)
}

/// `np.isclose(a, b, atol=0.02)` with numpy's default `rtol = 1e-5`.
fn is_close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 0.02 + 1e-5 * b.abs()
}

fn desired_pos(hand: V3, button: V3) -> V3 {
    let mut button = add(button, [0.0, 0.0, -0.07]);
    if !(is_close(hand[0], button[0]) && is_close(hand[2], button[2])) {
        button[1] = hand[1] - 0.1;
    } else {
        button[1] += 0.02;
    }
    button
}
