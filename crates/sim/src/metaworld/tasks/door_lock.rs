//! door-lock-v3: turn the lock on a closed door downwards.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{hamacher_product, norm, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "door-lock-v3",
    xml: "sawyer_xyz/sawyer_door_lock.xml",
    hand_low: [-0.5, 0.40, -0.15],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.8, 0.15],
    rand_high: &[0.1, 0.85, 0.15],
    goal_low: [-0.5, 0.40, -0.15],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

/// Goal relative to the lock link after the door settled.
const GOAL_OFFSET: [f64; 3] = [0.0, -0.04, -0.1];
/// Raw `mj_step`s the reset runs after moving the door.
const SETTLE_STEPS: usize = 5;
const LOCK_LENGTH: f64 = 0.1;
/// Per-axis weights of the pad-to-lock distance.
const SCALE: [f64; 3] = [0.25, 1.0, 0.5];
const SUCCESS_DISTANCE: f64 = 0.02;

#[derive(Debug)]
struct DoorLock {
    door: usize,
    door_link: usize,
    lock_link: usize,
    lock_start: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(DoorLock {
        door: scene.sim.body("door")?,
        door_link: scene.sim.body("door_link")?,
        lock_link: scene.sim.body("lock_link")?,
        lock_start: scene.sim.site("lockStartLock")?,
    }))
}

fn scaled_norm(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm([
        (a[0] - b[0]) * SCALE[0],
        (a[1] - b[1]) * SCALE[1],
        (a[2] - b[2]) * SCALE[2],
    ])
}

impl Task for DoorLock {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.sim.set_body_pos(self.door, [rv[0], rv[1], rv[2]]);
        // Plain mj_steps, the gripper controls left as the hand reset set them.
        scene.raw_steps(SETTLE_STEPS);
        // Kinematics of the last substep (no forward pass after it).
        let lock = scene.sim.body_xpos(self.lock_link);
        scene.obj_init_pos = lock;
        scene.target_pos = [
            lock[0] + GOAL_OFFSET[0],
            lock[1] + GOAL_OFFSET[1],
            lock[2] + GOAL_OFFSET[2],
        ];
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.lock_start));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.door_link));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let tcp = scene.left_pad_pos();
        let tcp_to_obj = scaled_norm(obj, tcp);
        // Python's `init_left_pad` is a live view of the left pad's position, so the margin
        // is the current distance itself.
        let tcp_to_obj_init = tcp_to_obj;
        let obj_to_target = (scene.target_pos[2] - obj[2]).abs();
        let tcp_opened = obs[3].max(0.0);

        let near_lock = tolerance(tcp_to_obj, (0.0, 0.01), tcp_to_obj_init, Sigmoid::LongTail);
        let lock_pressed = tolerance(obj_to_target, (0.0, 0.005), LOCK_LENGTH, Sigmoid::LongTail);
        Eval {
            reward: 2.0 * hamacher_product(tcp_opened, near_lock) + 8.0 * lock_pressed,
            success: obj_to_target <= SUCCESS_DISTANCE,
        }
    }
}
