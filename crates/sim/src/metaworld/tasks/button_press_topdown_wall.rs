//! button-press-topdown-wall-v3 (`metaworld/envs/sawyer_button_press_topdown_wall_v3.py`):
//! press a button down from above, behind a wall.
//!
//! button-press-topdown-v3's task ([`super::button_press_topdown`]), except that the gripper
//! term is `max(obs[3], 0)`.

use super::button_press::{self, Closed, Shaping, Variant};
use super::{button_press_topdown, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "button-press-topdown-wall-v3",
    xml: "sawyer_xyz/sawyer_button_press_topdown_wall.xml",
    ..button_press_topdown::SPEC
};

const VARIANT: Variant = Variant {
    shaping: Shaping::Sum {
        closed: Closed::Clamped,
        approach: 5.0,
        press: 5.0,
        press_within: 0.03,
    },
    ..button_press_topdown::VARIANT
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    button_press::build_with(scene, &SPEC, &VARIANT)
}
