//! sweep-into-v3: sweep a puck across the table into a hole.

use super::TaskSpec;
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "sweep-into-v3",
    xml: "sawyer_xyz/sawyer_table_with_hole.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.6, 0.02, -0.001, 0.8399, 0.0199],
    rand_high: &[0.1, 0.7, 0.02, 0.001, 0.8401, 0.0201],
    goal_low: [-0.001, 0.8399, 0.0199],
    goal_high: [0.001, 0.8401, 0.0201],
    rand_vec_ok: puck_away_from_hole,
};

/// The goal is this fixed point (`self.goal`); the goal part of `rand_vec` is unused.
const GOAL: [f64; 3] = [0.0, 0.84, 0.02];
/// Minimum planar distance of the puck's start from the goal (reset rejection rule).
const MIN_START_DISTANCE: f64 = 0.15;
const OBJ_RADIUS: f64 = 0.02;
const TARGET_RADIUS: f64 = 0.05;
/// Constants of the task's own `_gripper_caging_reward`.
const PAD_SUCCESS_MARGIN: f64 = 0.05;
const GRIP_SUCCESS_MARGIN: f64 = OBJ_RADIUS + 0.005;
const XZ_SUCCESS_MARGIN: f64 = 0.01;

/// The reset re-draws while the puck starts within 15 cm (in the plane) of the fixed goal.
fn puck_away_from_hole(rv: &[f64]) -> bool {
    let (dx, dy) = (rv[0] - GOAL[0], rv[1] - GOAL[1]);
    (dx * dx + dy * dy).sqrt() >= MIN_START_DISTANCE
}

#[derive(Debug)]
struct SweepInto {
    obj: usize,
    obj_geom: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(SweepInto {
        obj: scene.sim.body("obj")?,
        obj_geom: scene.sim.geom("objGeom")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

/// Distance in the x-z plane.
fn dist_xz(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl SweepInto {
    /// The task's `_gripper_caging_reward` override. Python's `init_left_pad`/`init_right_pad`
    /// are live views of `data.xpos`, so the caging margins use the *current* pad positions.
    fn caging_reward(&self, scene: &Scene, obj: [f64; 3]) -> f64 {
        let left = scene.left_pad_pos();
        let right = scene.right_pad_pos();
        let left_delta = left[1] - obj[1];
        let right_delta = obj[1] - right[1];
        let right_margin = ((obj[1] - right[1]).abs() - PAD_SUCCESS_MARGIN).abs();
        let left_margin = ((obj[1] - left[1]).abs() - PAD_SUCCESS_MARGIN).abs();
        let pad = |delta: f64, upper: f64, margin: f64| {
            tolerance(delta, (OBJ_RADIUS, upper), margin, Sigmoid::LongTail)
        };
        let y_caging = hamacher_product(
            pad(right_delta, PAD_SUCCESS_MARGIN, right_margin),
            pad(left_delta, PAD_SUCCESS_MARGIN, left_margin),
        );
        let y_gripping = hamacher_product(
            pad(right_delta, GRIP_SUCCESS_MARGIN, right_margin),
            pad(left_delta, GRIP_SUCCESS_MARGIN, left_margin),
        );
        let xz_margin = dist_xz(scene.obj_init_pos, scene.init_tcp) - XZ_SUCCESS_MARGIN;
        let xz_caging = tolerance(
            dist_xz(scene.tcp_center(), obj),
            (0.0, XZ_SUCCESS_MARGIN),
            xz_margin,
            Sigmoid::LongTail,
        );
        let caging = hamacher_product(y_caging, xz_caging);
        let gripping = if caging > 0.95 { y_gripping } else { 0.0 };
        (caging + gripping) / 2.0
    }
}

impl Task for SweepInto {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.target_pos = GOAL;
        // The puck keeps the height it settled at during the hand reset.
        let height = scene.body_com(self.obj)[2];
        scene.obj_init_pos = [rv[0], rv[1], height];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.obj));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.obj_geom)));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = [scene.target_pos[0], scene.target_pos[1], obj[2]];
        let obj_to_target = dist(obj, target);
        let in_place = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let object_grasped = self.caging_reward(scene, obj);
        let reward = if obj_to_target < TARGET_RADIUS {
            10.0
        } else {
            2.0 * object_grasped + 6.0 * hamacher_product(object_grasped, in_place)
        };
        Eval {
            reward,
            success: obj_to_target <= TARGET_RADIUS,
        }
    }
}
