//! window-open-v3: slide a horizontal window open by pushing its handle 20 cm along +x.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
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

/// How far the handle has to travel along x.
const OPEN_DISTANCE: f64 = 0.2;
const HANDLE_RADIUS: f64 = 0.02;

#[derive(Debug)]
struct WindowOpen {
    window: usize,
    handle: usize,
    slide_qpos: usize,
    handle_pos_init: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let slide = scene.sim.joint("window_slide")?;
    Ok(Box::new(WindowOpen {
        window: scene.sim.body("window")?,
        handle: scene.sim.site("handleOpenStart")?,
        slide_qpos: scene.sim.jnt_qposadr(slide),
        handle_pos_init: [0.0; 3],
    }))
}

impl Task for WindowOpen {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = [rv[0] + OPEN_DISTANCE, rv[1], rv[2]];
        scene.sim.set_body_pos(self.window, scene.obj_init_pos);
        // Read before any forward pass: the kinematics of the hand reset's last substep.
        self.handle_pos_init = scene.sim.site_xpos(self.handle);
        // Written without mj_forward; the reset observation keeps the stale kinematics.
        scene.sim.qpos_mut()[self.slide_qpos] = 0.0;
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

        let target_to_obj = (obj[0] - target[0]).abs();
        let target_to_obj_init = (scene.obj_init_pos[0] - target[0]).abs();
        let in_place = tolerance(
            target_to_obj,
            (0.0, TARGET_RADIUS),
            (target_to_obj_init - TARGET_RADIUS).abs(),
            Sigmoid::LongTail,
        );

        let tcp_to_obj = dist(obj, tcp);
        let tcp_to_obj_init = dist(self.handle_pos_init, scene.init_tcp);
        let reach = tolerance(
            tcp_to_obj,
            (0.0, HANDLE_RADIUS),
            (tcp_to_obj_init - HANDLE_RADIUS).abs(),
            Sigmoid::LongTail,
        );

        Eval {
            reward: 10.0 * hamacher_product(reach, in_place),
            success: target_to_obj <= TARGET_RADIUS,
        }
    }
}
