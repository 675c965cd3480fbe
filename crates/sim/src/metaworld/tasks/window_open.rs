//! window-open-v3 (`metaworld/envs/sawyer_window_open_v3.py`): slide a horizontal window open
//! by pushing its handle 20 cm along +x.
//!
//! The body of both window tasks: window-close builds it with [`Direction::Close`].

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, radius_tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "window-open-v3",
    xml: "sawyer_xyz/sawyer_window_horizontal.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.4f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.7, 0.16],
    rand_high: &[0.1, 0.9, 0.16],
    goal_low: [-0.5, 0.40, 0.05],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

/// How far the handle has to travel along x (window-close: how far the window starts open).
const OPEN_DISTANCE: f64 = 0.2;
const HANDLE_RADIUS: f64 = 0.02;

/// Which way the window is slid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Direction {
    /// window-open-v3: from closed to `OPEN_DISTANCE` along +x; the reach term is long-tailed.
    Open,
    /// window-close-v3: from `OPEN_DISTANCE` open back to closed; the reach term is Gaussian.
    Close,
}

#[derive(Debug)]
struct Window {
    spec: &'static TaskSpec,
    direction: Direction,
    window: usize,
    handle: usize,
    slide_qpos: usize,
    handle_pos_init: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, Direction::Open, "handleOpenStart")
}

/// A window task sliding the other way, observing the handle at `handle_site`.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    direction: Direction,
    handle_site: &str,
) -> Result<Box<dyn Task>> {
    let slide = scene.sim.joint("window_slide")?;
    Ok(Box::new(Window {
        spec,
        direction,
        window: scene.sim.body("window")?,
        handle: scene.sim.site(handle_site)?,
        slide_qpos: scene.sim.jnt_qposadr(slide),
        handle_pos_init: [0.0; 3],
    }))
}

impl Task for Window {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        match self.direction {
            Direction::Open => {
                scene.target_pos = [rv[0] + OPEN_DISTANCE, rv[1], rv[2]];
                scene.sim.set_body_pos(self.window, scene.obj_init_pos);
                // Read before any forward pass: the kinematics of the hand reset's last substep.
                self.handle_pos_init = scene.sim.site_xpos(self.handle);
                // Written without mj_forward; the reset observation keeps the stale kinematics.
                scene.sim.qpos_mut()[self.slide_qpos] = 0.0;
            }
            Direction::Close => {
                scene.target_pos = scene.obj_init_pos;
                scene.sim.set_body_pos(self.window, scene.obj_init_pos);
                // The handle is read while the window is still closed (kinematics of the hand
                // reset's last substep) and shifted by hand to where opening the window will
                // put it.
                let [x, y, z] = scene.sim.site_xpos(self.handle);
                self.handle_pos_init = [x + OPEN_DISTANCE, y, z];
                // Opened without mj_forward: the reset observation still shows the closed
                // window.
                scene.sim.qpos_mut()[self.slide_qpos] = OPEN_DISTANCE;
            }
        }
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.handle));
    }

    fn evaluate(&mut self, scene: &Scene, _obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = scene.sim.site_xpos(self.handle);
        let tcp = scene.tcp_center();
        let target = scene.target_pos;
        let (obj_init_x, reach_sigmoid) = match self.direction {
            Direction::Open => (scene.obj_init_pos[0], Sigmoid::LongTail),
            Direction::Close => (self.handle_pos_init[0], Sigmoid::Gaussian),
        };

        let target_to_obj = (obj[0] - target[0]).abs();
        let target_to_obj_init = (obj_init_x - target[0]).abs();
        let in_place = radius_tolerance(
            target_to_obj,
            TARGET_RADIUS,
            target_to_obj_init,
            Sigmoid::LongTail,
        );

        let tcp_to_obj = dist(obj, tcp);
        let tcp_to_obj_init = dist(self.handle_pos_init, scene.init_tcp);
        let reach = radius_tolerance(tcp_to_obj, HANDLE_RADIUS, tcp_to_obj_init, reach_sigmoid);

        Eval {
            reward: 10.0 * hamacher_product(reach, in_place),
            success: target_to_obj <= TARGET_RADIUS,
        }
    }
}
