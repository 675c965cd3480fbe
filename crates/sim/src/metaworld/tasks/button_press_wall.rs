//! button-press-wall-v3 (`metaworld/envs/sawyer_button_press_wall_v3.py`): press a button
//! along +y behind a low wall.
//!
//! button-press-v3's task ([`super::button_press`]) with its own reward shape and radii.

use super::button_press::{self, Shaping, Variant};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "button-press-wall-v3",
    xml: "sawyer_xyz/sawyer_button_press_wall.xml",
    rand_low: &[-0.05, 0.85, 0.1149],
    rand_high: &[0.05, 0.9, 0.1151],
    ..button_press::SPEC
};

const VARIANT: Variant = Variant {
    axis: 1,
    face_offset: -0.193,
    zero_button_joint: true,
    near_radius: 0.01,
    // Beyond 7 cm hand-to-button distance only the approach is rewarded.
    shaping: Shaping::Wall { far: 0.07 },
    success_distance: 0.03,
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    button_press::build_with(scene, &SPEC, &VARIANT)
}
