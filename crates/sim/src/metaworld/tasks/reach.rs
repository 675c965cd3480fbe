//! reach-v3: move the gripper to a goal in the air.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

pub const SPEC: TaskSpec = TaskSpec {
    name: "reach-v3",
    xml: "sawyer_xyz/sawyer_reach_v3.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.1, 0.6, 0.02, -0.1, 0.8, 0.05],
    rand_high: &[0.1, 0.7, 0.02, 0.1, 0.9, 0.3],
    goal_low: [-0.1, 0.8, 0.05],
    goal_high: [0.1, 0.9, 0.3],
    rand_vec_ok: obj_goal_apart::<15>,
};

#[derive(Debug)]
struct Reach {
    spec: &'static TaskSpec,
    obj: usize,
    obj_geom: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC)
}

/// The reach task with another layout (reach-wall-v3: same reset, observation and reward,
/// another model and ranges).
pub(super) fn build_with(scene: &Scene, spec: &'static TaskSpec) -> Result<Box<dyn Task>> {
    Ok(Box::new(Reach {
        spec,
        obj: scene.sim.body("obj")?,
        obj_geom: scene.sim.geom("objGeom")?,
    }))
}

impl Task for Reach {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.target_pos = [rv[3], rv[4], rv[5]];
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.obj));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.obj_geom)));
    }

    fn evaluate(&mut self, scene: &Scene, _obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let tcp_to_target = dist(scene.tcp_center(), scene.target_pos);
        let in_place_margin = dist(scene.hand_init_pos, scene.target_pos);
        let in_place = tolerance(
            tcp_to_target,
            (0.0, TARGET_RADIUS),
            in_place_margin,
            Sigmoid::LongTail,
        );
        Eval {
            reward: 10.0 * in_place,
            success: tcp_to_target <= 0.05,
        }
    }
}
