//! plate-slide-back-v3: slide a puck out of the cabinet, back towards the robot, into a goal.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "plate-slide-back-v3",
    xml: "sawyer_xyz/sawyer_plate_slide.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // Python declares it as float32.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[0.0, 0.85, 0.0, -0.1, 0.6, 0.015],
    rand_high: &[0.0, 0.85, 0.0, 0.1, 0.6, 0.015],
    goal_low: [-0.1, 0.6, 0.015],
    goal_high: [0.1, 0.6, 0.015],
    rand_vec_ok: always_ok,
};

/// The puck's two slide joints (`qpos[9..11]`).
pub(super) const PUCK_QPOS: std::ops::Range<usize> = 9..11;
const SUCCESS_RADIUS: f64 = 0.07;

#[derive(Debug)]
struct PlateSlideBack {
    puck: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PlateSlideBack {
        puck: scene.sim.geom("puck")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

/// Sets the puck's slide joints (velocities untouched) and runs `mj_forward`: the task's
/// `_set_obj_xyz`.
pub(super) fn set_puck_joints(scene: &mut Scene, joints: [f64; 2]) {
    let mut qpos = scene.sim.qpos().to_vec();
    let qvel = scene.sim.qvel().to_vec();
    qpos[PUCK_QPOS].copy_from_slice(&joints);
    scene.set_state(&qpos, &qvel);
}

/// The puck's position and scipy quaternion (x, y, z, w), obs[4..11].
pub(super) fn puck_objects(scene: &Scene, puck: usize, out: &mut [f64; 14]) {
    out[..3].copy_from_slice(&scene.sim.geom_xpos(puck));
    out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(puck)));
}

/// The v2 reward of plate-slide-back, -side and -back-side: 1.5 × reach reward, `2 + 7 ×
/// in-place` once the TCP is low (z ≤ 0.03) and within 7 cm of the puck, 10 inside the target
/// radius; success within 7 cm of the goal.
pub(super) fn low_push_eval(scene: &Scene, obs: &[f64; OBS_DIM]) -> Eval {
    let tcp = scene.tcp_center();
    let obj = [obs[4], obs[5], obs[6]];
    let target = scene.target_pos;
    let obj_to_target = dist(obj, target);
    let in_place = tolerance(
        obj_to_target,
        (0.0, TARGET_RADIUS),
        dist(scene.obj_init_pos, target) - TARGET_RADIUS,
        Sigmoid::LongTail,
    );
    let tcp_to_obj = dist(tcp, obj);
    let object_grasped = tolerance(
        tcp_to_obj,
        (0.0, TARGET_RADIUS),
        dist(scene.init_tcp, scene.obj_init_pos) - TARGET_RADIUS,
        Sigmoid::LongTail,
    );
    let mut reward = 1.5 * object_grasped;
    if tcp[2] <= 0.03 && tcp_to_obj < 0.07 {
        reward = 2.0 + 7.0 * in_place;
    }
    if obj_to_target < TARGET_RADIUS {
        reward = 10.0;
    }
    Eval {
        reward,
        success: obj_to_target <= SUCCESS_RADIUS,
    }
}

impl Task for PlateSlideBack {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = [rv[3], rv[4], rv[5]];
        // Python writes `data.body("puck_goal").xpos`, which the next mj_forward overwrites:
        // the goal marker stays where the model has it.
        set_puck_joints(scene, [0.0, 0.15]);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        puck_objects(scene, self.puck, out);
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        low_push_eval(scene, obs)
    }
}
