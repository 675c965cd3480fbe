//! handle-pull-v3 (`metaworld/envs/sawyer_handle_pull_v3.py`): grab a handle from below and
//! pull it up.
//!
//! The body of both handle-pull tasks: handle-pull-side builds it with [`Layout::Side`].

use super::{handle_press, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "handle-pull-v3",
    goal_high: [0.1, 0.70, 0.18],
    ..handle_press::SPEC
};

/// The handle joint's coordinate (`qpos[9]`) and velocity (`qvel[9]`).
const HANDLE_QPOS: usize = 9;
/// Handle joint position written at reset (pressed down).
const HANDLE_INIT_QPOS: f64 = -0.1;
/// handle-pull-side's success: the handle centre within this distance of the goal.
const SIDE_SUCCESS_DISTANCE: f64 = 0.08;

/// Where the handle sticks out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Layout {
    /// handle-pull-v3: the handle's right end is observed; distances to the goal are in z.
    Front,
    /// handle-pull-side-v3: the handle's centre is observed and `obj_init_pos` is its start;
    /// distances to the goal are Euclidean.
    Side,
}

#[derive(Debug)]
struct HandlePull {
    spec: &'static TaskSpec,
    layout: Layout,
    box_body: usize,
    handle: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, Layout::Front)
}

/// The handle-pull task with another layout.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    layout: Layout,
) -> Result<Box<dyn Task>> {
    let handle_site = match layout {
        Layout::Front => "handleRight",
        Layout::Side => "handleCenter",
    };
    Ok(Box::new(HandlePull {
        spec,
        layout,
        box_body: scene.sim.body("box")?,
        handle: scene.sim.site(handle_site)?,
        goal_site: scene.sim.site("goalPull")?,
    }))
}

impl Task for HandlePull {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        match self.layout {
            Layout::Front => {
                scene.obj_init_pos = [rv[0], rv[1], rv[2]];
                scene.sim.set_body_pos(self.box_body, scene.obj_init_pos);
                scene.set_scalar_joint(HANDLE_QPOS, HANDLE_QPOS, HANDLE_INIT_QPOS);
                scene.target_pos = scene.sim.site_xpos(self.goal_site);
            }
            Layout::Side => {
                scene.sim.set_body_pos(self.box_body, [rv[0], rv[1], rv[2]]);
                scene.set_scalar_joint(HANDLE_QPOS, HANDLE_QPOS, HANDLE_INIT_QPOS);
                scene.target_pos = scene.sim.site_xpos(self.goal_site);
                // `obj_init_pos` ends up as the handle's start, not the box position.
                scene.obj_init_pos = scene.sim.site_xpos(self.handle);
            }
        }
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
        let (target_to_obj, target_to_obj_init) = match self.layout {
            Layout::Front => (
                (target[2] - obj[2]).abs(),
                (target[2] - scene.obj_init_pos[2]).abs(),
            ),
            Layout::Side => (dist(obj, target), dist(scene.obj_init_pos, target)),
        };
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let (obj_radius, pad_success_thresh) = match self.layout {
            Layout::Front => (0.022, 0.05),
            Layout::Side => (0.032, 0.06),
        };
        let object_grasped = scene.gripper_caging_reward(
            action,
            obj,
            obj_radius,
            pad_success_thresh,
            0.01,
            0.01,
            1.0,
            Density::High,
        );
        let mut reward = hamacher_product(object_grasped, in_place);
        let tcp_to_obj = dist(obj, scene.tcp_center());
        // handle-pull's Python compares the handle's y (not z) with the box's start height.
        let lifted = match self.layout {
            Layout::Front => obj[1],
            Layout::Side => obj[2],
        };
        if tcp_to_obj < 0.035 && obs[3] > 0.0 && lifted - 0.01 > scene.obj_init_pos[2] {
            reward += 1.0 + 5.0 * in_place;
        }
        if target_to_obj < TARGET_RADIUS {
            reward = 10.0;
        }
        let success_distance = match self.layout {
            Layout::Front => TARGET_RADIUS,
            Layout::Side => SIDE_SUCCESS_DISTANCE,
        };
        Eval {
            reward,
            success: target_to_obj <= success_distance,
        }
    }
}
