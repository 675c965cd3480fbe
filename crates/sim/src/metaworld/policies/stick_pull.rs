//! `SawyerStickPullV3Policy`: grasp the stick, hook it into the container's handle, then pull
//! towards 5 cm short of the goal in x.

use super::stick_push::stick_action;
use crate::metaworld::{ACTION_DIM, OBS_DIM};

pub fn action(obs: &[f64; OBS_DIM]) -> [f32; ACTION_DIM] {
    stick_action(
        obs,
        [-0.015, 0.0, 0.03],
        [-0.015, 0.0, 0.03],
        [-0.05, 0.0, 0.0],
        25.0,
    )
}
