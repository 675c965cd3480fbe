//! door-unlock-v3: push the lock on a closed door sideways to unlock it.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{norm, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "door-unlock-v3",
    xml: "sawyer_xyz/sawyer_door_lock.xml",
    hand_low: [-0.5, 0.40, -0.15],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.8, 0.15],
    rand_high: &[0.1, 0.85, 0.15],
    goal_low: [0.0, 0.64, 0.2100],
    goal_high: [0.2, 0.7, 0.2111],
    rand_vec_ok: always_ok,
};

/// The lock joint (`qpos[9]`, `qvel[9]` in Python).
const LOCK_JOINT_ADR: usize = 9;
/// Lock angle at the start (locked). Python's literal, not exactly pi/2.
#[allow(clippy::approx_constant)]
const LOCKED_ANGLE: f64 = 1.5708;
/// Goal relative to the lock link.
const GOAL_OFFSET: [f64; 3] = [0.1, -0.04, 0.0];
/// Offset from the hand to its "shoulder", which should line up with the lock.
const SHOULDER_OFFSET: [f64; 3] = [0.0, 0.055, 0.07];
const SCALE: [f64; 3] = [0.25, 1.0, 0.5];
const LOCK_LENGTH: f64 = 0.1;
const SUCCESS_DISTANCE: f64 = 0.02;

#[derive(Debug)]
struct DoorUnlock {
    door: usize,
    door_link: usize,
    lock_link: usize,
    lock_start: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(DoorUnlock {
        door: scene.sim.body("door")?,
        door_link: scene.sim.body("door_link")?,
        lock_link: scene.sim.body("lock_link")?,
        lock_start: scene.sim.site("lockStartUnlock")?,
    }))
}

/// `(from + SHOULDER_OFFSET - to) * SCALE`, as a norm.
fn shoulder_distance(from: [f64; 3], to: [f64; 3]) -> f64 {
    norm(std::array::from_fn(|i| {
        (from[i] + SHOULDER_OFFSET[i] - to[i]) * SCALE[i]
    }))
}

impl Task for DoorUnlock {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.sim.set_body_pos(self.door, [rv[0], rv[1], rv[2]]);
        scene.set_scalar_joint(LOCK_JOINT_ADR, LOCK_JOINT_ADR, LOCKED_ANGLE);
        let lock = scene.sim.body_xpos(self.lock_link);
        scene.obj_init_pos = lock;
        scene.target_pos = std::array::from_fn(|i| lock[i] + GOAL_OFFSET[i]);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.lock_start));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.door_link));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let gripper = [obs[0], obs[1], obs[2]];
        let lock = [obs[4], obs[5], obs[6]];
        // Python's `obj_init_pos` is a live view of the lock link's position.
        let lock_link = scene.sim.body_xpos(self.lock_link);
        let ready_to_push = tolerance(
            shoulder_distance(gripper, lock),
            (0.0, 0.02),
            shoulder_distance(scene.init_tcp, lock_link),
            Sigmoid::LongTail,
        );
        let obj_to_target = (scene.target_pos[0] - lock[0]).abs();
        let pushed = tolerance(obj_to_target, (0.0, 0.005), LOCK_LENGTH, Sigmoid::LongTail);
        Eval {
            reward: 2.0 * ready_to_push + 8.0 * pushed,
            success: obj_to_target <= SUCCESS_DISTANCE,
        }
    }
}
