//! handle-press-v3 (`metaworld/envs/sawyer_handle_press_v3.py`): press a handle down.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, radius_tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "handle-press-v3",
    xml: "sawyer_xyz/sawyer_handle_press.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.8, -0.001],
    rand_high: &[0.1, 0.9, 0.001],
    goal_low: [-0.1, 0.55, 0.04],
    goal_high: [0.1, 0.70, 0.08],
    rand_vec_ok: always_ok,
};

/// The handle joint's coordinate (`qpos[9]`) and velocity (`qvel[9]`).
const HANDLE_QPOS: usize = 9;
/// Handle joint position written at reset.
const HANDLE_INIT_QPOS: f64 = -0.001;
/// The task's `TARGET_RADIUS` (tighter than the shared one).
const TARGET_RADIUS: f64 = 0.02;
const HANDLE_RADIUS: f64 = 0.02;

#[derive(Debug)]
struct HandlePress {
    spec: &'static TaskSpec,
    box_body: usize,
    handle: usize,
    goal_site: usize,
    /// Handle position right after the reset (`_handle_init_pos`).
    handle_init_pos: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC)
}

/// The handle-press task with another layout (handle-press-side-v3: same reset, observation
/// and reward, a sideways handle and other ranges).
pub(super) fn build_with(scene: &Scene, spec: &'static TaskSpec) -> Result<Box<dyn Task>> {
    Ok(Box::new(HandlePress {
        spec,
        box_body: scene.sim.body("box")?,
        handle: scene.sim.site("handleStart")?,
        goal_site: scene.sim.site("goalPress")?,
        handle_init_pos: [0.0; 3],
    }))
}

impl Task for HandlePress {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.box_body, scene.obj_init_pos);
        // The task's `_set_obj_xyz`: only the handle joint, then `set_state` (mj_forward).
        let mut qpos = scene.sim.qpos().to_vec();
        let mut qvel = scene.sim.qvel().to_vec();
        qpos[HANDLE_QPOS] = HANDLE_INIT_QPOS;
        qvel[HANDLE_QPOS] = 0.0;
        scene.set_state(&qpos, &qvel);
        scene.target_pos = scene.sim.site_xpos(self.goal_site);
        self.handle_init_pos = scene.sim.site_xpos(self.handle);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.handle));
    }

    fn evaluate(&mut self, scene: &Scene, _obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = scene.sim.site_xpos(self.handle);
        let target = scene.target_pos;
        let target_to_obj = (obj[2] - target[2]).abs();
        let target_to_obj_init = (self.handle_init_pos[2] - target[2]).abs();
        let in_place = radius_tolerance(
            target_to_obj,
            TARGET_RADIUS,
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let tcp_to_obj_init = dist(self.handle_init_pos, scene.init_tcp);
        let reach = radius_tolerance(
            tcp_to_obj,
            HANDLE_RADIUS,
            tcp_to_obj_init,
            Sigmoid::LongTail,
        );
        let success = target_to_obj <= TARGET_RADIUS;
        let reward = if success {
            1.0
        } else {
            hamacher_product(reach, in_place)
        };
        Eval {
            reward: 10.0 * reward,
            success,
        }
    }
}
