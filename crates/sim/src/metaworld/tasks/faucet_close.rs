//! faucet-close-v3 (`metaworld/envs/sawyer_faucet_close_v3.py`): rotate the faucet handle to
//! the closed side (-x).
//!
//! faucet-open-v3's task ([`super::faucet_open`]) with the goal on the other side.

use super::faucet_open::{self, Variant, HANDLE_LENGTH};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "faucet-close-v3",
    rand_low: &[-0.1, 0.8, 0.0],
    rand_high: &[0.1, 0.85, 0.0],
    ..faucet_open::SPEC
};

const VARIANT: Variant = Variant {
    handle_site: "handleStartClose",
    goal_site: "goal_close",
    goal_offset: [-HANDLE_LENGTH, 0.0, 0.125],
    // Unlike faucet-open, the reset ends with a kinematics pass (before the goal site moves).
    forward_at_reset: true,
    // The reward measures the observed handle point itself.
    reward_handle_offset: None,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    faucet_open::build_with(scene, &SPEC, &VARIANT)
}
