//! button-press-topdown-v3 (`metaworld/envs/sawyer_button_press_topdown_v3.py`): press a
//! button down from above.
//!
//! button-press-v3's task ([`super::button_press`]) along z, with its own reward weights.

use super::button_press::{self, Closed, Shaping, Variant};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "button-press-topdown-v3",
    xml: "sawyer_xyz/sawyer_button_press_topdown.xml",
    rand_low: &[-0.1, 0.8, 0.115],
    ..button_press::SPEC
};

/// button-press-topdown-v3's variant: the button top is 0.193 above the button body; the
/// reset only runs a forward pass.
pub(super) const VARIANT: Variant = Variant {
    axis: 2,
    face_offset: 0.193,
    zero_button_joint: false,
    near_radius: 0.01,
    shaping: Shaping::Sum {
        closed: Closed::Inverted,
        approach: 5.0,
        press: 5.0,
        press_within: 0.03,
    },
    success_distance: 0.024,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    button_press::build_with(scene, &SPEC, &VARIANT)
}
