//! sweep-into-v3: sweep a puck across the table into a hole.

use super::pad_caging::PadCaging;
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
const TARGET_RADIUS: f64 = 0.05;
/// Constants of the task's own `_gripper_caging_reward`.
const CAGING: PadCaging = PadCaging {
    obj_radius: 0.02,
    grip_extra: 0.005,
    xz_success_margin: 0.01,
};

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
        let object_grasped = CAGING.reward(scene, obj);
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
