//! window-close-v3 (`metaworld/envs/sawyer_window_close_v3.py`): slide an open horizontal
//! window shut by pushing its handle back along -x.
//!
//! window-open-v3's task ([`super::window_open`]) slid the other way.

use super::window_open::{self, Direction};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "window-close-v3",
    rand_low: &[0.0, 0.75, 0.2],
    rand_high: &[0.0, 0.9, 0.2],
    ..window_open::SPEC
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    window_open::build_with(scene, &SPEC, Direction::Close, "handleCloseStart")
}
