//! `SawyerWindowOpenV3Policy`: beside the handle, down, slide it along +x.

use super::{above_down_push, act, hand, object};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    let hand = hand(obs);
    let to = above_down_push(
        hand,
        object(obs),
        [-0.03, -0.03, -0.08],
        (0.04, 0.3, 0.02),
        [0.1, 0.0, 0.0],
    );
    act(hand, to, 25.0, 1.0)
}
