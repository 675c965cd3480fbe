//! drawer-open-v3 (`metaworld/envs/sawyer_drawer_open_v3.py`): pull a drawer open by its
//! handle.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, scaled_dist, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "drawer-open-v3",
    xml: "sawyer_xyz/sawyer_drawer.xml",
    hand_low: HAND_LOW,
    hand_high: HAND_HIGH,
    mocap_low: None,
    mocap_high: None,
    // Python stores it as float32.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.9, 0.0],
    rand_high: &[0.1, 0.9, 0.0],
    goal_low: HAND_LOW,
    goal_high: HAND_HIGH,
    rand_vec_ok: always_ok,
};

const HAND_LOW: [f64; 3] = [-0.5, 0.40, 0.05];
const HAND_HIGH: [f64; 3] = [0.5, 1.0, 0.5];
/// How far the drawer opens (`maxDist`).
const MAX_DIST: f64 = 0.2;
/// Handle position relative to the drawer link.
const HANDLE_OFFSET: [f64; 3] = [0.0, -0.16, 0.0];
/// Success: the handle within this distance of the goal.
const SUCCESS_DIST: f64 = 0.03;

#[derive(Debug)]
struct DrawerOpen {
    drawer: usize,
    drawer_link: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(DrawerOpen {
        drawer: scene.sim.body("drawer")?,
        drawer_link: scene.sim.body("drawer_link")?,
    }))
}

impl Task for DrawerOpen {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.drawer, scene.obj_init_pos);
        let goal_offset = [0.0, -0.16 - MAX_DIST, 0.09];
        scene.target_pos = std::array::from_fn(|i| scene.obj_init_pos[i] + goal_offset[i]);
        scene.set_site_pos("goal", scene.target_pos)?;
        // No mj_forward: the reset observation keeps the kinematics of the last substep.
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        let link = scene.body_com(self.drawer_link);
        for i in 0..3 {
            out[i] = link[i] + HANDLE_OFFSET[i];
        }
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.drawer_link));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let gripper = [obs[0], obs[1], obs[2]];
        let handle = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let handle_error = dist(handle, target);
        let opening = tolerance(handle_error, (0.0, 0.02), MAX_DIST, Sigmoid::LongTail);

        // x/y errors weigh more so the gripper can drop down next to the handle.
        let scale = [3.0, 3.0, 1.0];
        let handle_pos_init = [target[0], target[1] + MAX_DIST, target[2]];
        let caging = tolerance(
            scaled_dist(handle, gripper, scale),
            (0.0, 0.01),
            scaled_dist(handle_pos_init, scene.init_tcp, scale),
            Sigmoid::LongTail,
        );
        Eval {
            reward: 5.0 * (caging + opening),
            success: handle_error <= SUCCESS_DIST,
        }
    }
}
