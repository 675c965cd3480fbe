//! plate-slide-v3: slide a puck across the table into a goal.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "plate-slide-v3",
    xml: "sawyer_xyz/sawyer_plate_slide.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // Python declares it as float32.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[0.0, 0.6, 0.0, -0.1, 0.85, 0.0],
    rand_high: &[0.0, 0.6, 0.0, 0.1, 0.9, 0.0],
    goal_low: [-0.1, 0.85, 0.0],
    goal_high: [0.1, 0.9, 0.0],
    rand_vec_ok: always_ok,
};

/// The puck's two slide joints (`qpos[9..11]`).
const PUCK_QPOS: std::ops::Range<usize> = 9..11;
const TARGET_RADIUS: f64 = 0.05;
const SUCCESS_RADIUS: f64 = 0.07;

#[derive(Debug)]
struct PlateSlide {
    puck: usize,
    puck_goal: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PlateSlide {
        puck: scene.sim.geom("puck")?,
        puck_goal: scene.sim.body("puck_goal")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

impl Task for PlateSlide {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.sim.set_body_pos(self.puck_goal, scene.target_pos);
        // The task's `_set_obj_xyz`: puck joints to zero, velocities untouched, mj_forward.
        let mut qpos = scene.sim.qpos().to_vec();
        let qvel = scene.sim.qvel().to_vec();
        qpos[PUCK_QPOS].fill(0.0);
        scene.set_state(&qpos, &qvel);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.geom_xpos(self.puck));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.puck)));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let obj_to_target = dist(obj, target);
        let in_place = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let object_grasped = tolerance(
            dist(scene.tcp_center(), obj),
            (0.0, TARGET_RADIUS),
            dist(scene.init_tcp, scene.obj_init_pos),
            Sigmoid::LongTail,
        );
        let reward = if obj_to_target < TARGET_RADIUS {
            10.0
        } else {
            8.0 * hamacher_product(object_grasped, in_place)
        };
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_RADIUS,
        }
    }
}
