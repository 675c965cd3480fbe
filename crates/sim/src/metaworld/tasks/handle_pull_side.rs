//! handle-pull-side-v3: pull up a handle that sticks out sideways, on the left of the table.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "handle-pull-side-v3",
    xml: "sawyer_xyz/sawyer_handle_press_sideways.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.35, 0.65, 0.0],
    rand_high: &[-0.25, 0.75, 0.0],
    goal_low: [-0.5, 0.40, 0.05],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

/// The handle joint's coordinate (`qpos[9]`) and velocity (`qvel[9]`).
const HANDLE_QPOS: usize = 9;
/// Handle joint position written at reset (pressed down).
const HANDLE_INIT_QPOS: f64 = -0.1;
/// Success: the handle centre within this distance of the goal.
const SUCCESS_DISTANCE: f64 = 0.08;

#[derive(Debug)]
struct HandlePullSide {
    box_body: usize,
    handle: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(HandlePullSide {
        box_body: scene.sim.body("box")?,
        handle: scene.sim.site("handleCenter")?,
        goal_site: scene.sim.site("goalPull")?,
    }))
}

impl Task for HandlePullSide {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.sim.set_body_pos(self.box_body, [rv[0], rv[1], rv[2]]);
        scene.set_scalar_joint(HANDLE_QPOS, HANDLE_QPOS, HANDLE_INIT_QPOS);
        scene.target_pos = scene.sim.site_xpos(self.goal_site);
        // `obj_init_pos` ends up as the handle's start, not the box position.
        scene.obj_init_pos = scene.sim.site_xpos(self.handle);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.handle));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let target_to_obj = dist(obj, target);
        let target_to_obj_init = dist(scene.obj_init_pos, target);
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let object_grasped =
            scene.gripper_caging_reward(action, obj, 0.032, 0.06, 0.01, 0.01, 1.0, Density::High);
        let mut reward = hamacher_product(object_grasped, in_place);
        let tcp_to_obj = dist(obj, scene.tcp_center());
        if tcp_to_obj < 0.035 && obs[3] > 0.0 && obj[2] - 0.01 > scene.obj_init_pos[2] {
            reward += 1.0 + 5.0 * in_place;
        }
        if target_to_obj < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: target_to_obj <= SUCCESS_DISTANCE,
        }
    }
}
