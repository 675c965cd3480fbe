//! `SawyerReachV3Policy`: move straight to the goal.

use super::{act, goal, hand};
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    act(hand(obs), goal(obs), 5.0, 0.0)
}
