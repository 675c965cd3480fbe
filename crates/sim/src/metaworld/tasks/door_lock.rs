//! door-lock-v3 (`metaworld/envs/sawyer_door_lock_v3.py`): turn the lock on a closed door
//! downwards.
//!
//! The body of both door-lock tasks: door-unlock builds it with [`Turn::Unlock`].

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{add, hamacher_product, scaled_dist, tolerance, Sigmoid};
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

/// door-lock: goal relative to the lock link after the door settled.
const LOCK_GOAL_OFFSET: [f64; 3] = [0.0, -0.04, -0.1];
/// door-lock: raw `mj_step`s the reset runs after moving the door.
const SETTLE_STEPS: usize = 5;
/// door-unlock: the lock joint (`qpos[9]`, `qvel[9]` in Python).
const LOCK_JOINT_ADR: usize = 9;
/// door-unlock: lock angle at the start (locked). Python's literal, not exactly pi/2.
#[allow(clippy::approx_constant)]
const LOCKED_ANGLE: f64 = 1.5708;
/// door-unlock: goal relative to the lock link.
const UNLOCK_GOAL_OFFSET: [f64; 3] = [0.1, -0.04, 0.0];
/// door-unlock: offset from the hand to its "shoulder", which should line up with the lock.
const SHOULDER_OFFSET: [f64; 3] = [0.0, 0.055, 0.07];
const LOCK_LENGTH: f64 = 0.1;
/// Per-axis weights of the hand-to-lock distance.
const SCALE: [f64; 3] = [0.25, 1.0, 0.5];
const SUCCESS_DISTANCE: f64 = 0.02;

/// Which way the lock is turned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Turn {
    /// door-lock-v3: down (along -z), reached with the left pad.
    Lock,
    /// door-unlock-v3: sideways (along +x), pushed with the hand's "shoulder".
    Unlock,
}

#[derive(Debug)]
struct DoorLock {
    spec: &'static TaskSpec,
    turn: Turn,
    door: usize,
    door_link: usize,
    lock_link: usize,
    lock_start: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, Turn::Lock)
}

/// The door-lock task turned the other way.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    turn: Turn,
) -> Result<Box<dyn Task>> {
    let lock_start = match turn {
        Turn::Lock => "lockStartLock",
        Turn::Unlock => "lockStartUnlock",
    };
    Ok(Box::new(DoorLock {
        spec,
        turn,
        door: scene.sim.body("door")?,
        door_link: scene.sim.body("door_link")?,
        lock_link: scene.sim.body("lock_link")?,
        lock_start: scene.sim.site(lock_start)?,
    }))
}

impl Task for DoorLock {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.sim.set_body_pos(self.door, [rv[0], rv[1], rv[2]]);
        let goal_offset = match self.turn {
            Turn::Lock => {
                // Plain mj_steps, the gripper controls left as the hand reset set them.
                scene.raw_steps(SETTLE_STEPS);
                // Kinematics of the last substep (no forward pass after it).
                LOCK_GOAL_OFFSET
            }
            Turn::Unlock => {
                scene.set_scalar_joint(LOCK_JOINT_ADR, LOCK_JOINT_ADR, LOCKED_ANGLE);
                UNLOCK_GOAL_OFFSET
            }
        };
        let lock = scene.sim.body_xpos(self.lock_link);
        scene.obj_init_pos = lock;
        scene.target_pos = add(lock, goal_offset);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.lock_start));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.door_link));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let gripper = [obs[0], obs[1], obs[2]];
        let lock = [obs[4], obs[5], obs[6]];
        match self.turn {
            Turn::Lock => {
                let tcp = scene.left_pad_pos();
                let tcp_to_obj = scaled_dist(lock, tcp, SCALE);
                // Python's `init_left_pad` is a live view of the left pad's position, so the
                // margin is the current distance itself.
                let tcp_to_obj_init = tcp_to_obj;
                let obj_to_target = (scene.target_pos[2] - lock[2]).abs();
                let tcp_opened = obs[3].max(0.0);

                let near_lock =
                    tolerance(tcp_to_obj, (0.0, 0.01), tcp_to_obj_init, Sigmoid::LongTail);
                let lock_pressed =
                    tolerance(obj_to_target, (0.0, 0.005), LOCK_LENGTH, Sigmoid::LongTail);
                Eval {
                    reward: 2.0 * hamacher_product(tcp_opened, near_lock) + 8.0 * lock_pressed,
                    success: obj_to_target <= SUCCESS_DISTANCE,
                }
            }
            Turn::Unlock => {
                // `(from + SHOULDER_OFFSET - to) * SCALE`, as a norm.
                let shoulder_distance =
                    |from: [f64; 3], to| scaled_dist(add(from, SHOULDER_OFFSET), to, SCALE);
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
    }
}
