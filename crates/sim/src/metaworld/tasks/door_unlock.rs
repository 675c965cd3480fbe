//! door-unlock-v3 (`metaworld/envs/sawyer_door_unlock_v3.py`): push the lock on a closed door
//! sideways to unlock it.
//!
//! door-lock-v3's task ([`super::door_lock`]) turned the other way.

use super::door_lock::{self, Turn};
use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::{Scene, Task};

pub const SPEC: TaskSpec = TaskSpec {
    name: "door-unlock-v3",
    goal_low: [0.0, 0.64, 0.2100],
    goal_high: [0.2, 0.7, 0.2111],
    ..door_lock::SPEC
};

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    door_lock::build_with(scene, &SPEC, Turn::Unlock)
}
