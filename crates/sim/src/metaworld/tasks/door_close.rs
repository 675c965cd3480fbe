//! door-close-v3: swing an open door shut by pushing it.

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "door-close-v3",
    xml: "sawyer_xyz/sawyer_door_pull.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [-0.5, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[0.0, 0.85, 0.15],
    rand_high: &[0.1, 0.95, 0.15],
    goal_low: [0.2, 0.65, 0.1499],
    goal_high: [0.3, 0.75, 0.1501],
    rand_vec_ok: always_ok,
};

/// Goal relative to the door body.
const GOAL_OFFSET: [f64; 3] = [0.2, -0.2, 0.0];
/// Hinge angle the door starts at (open). Python's literal, not exactly -pi/2.
#[allow(clippy::approx_constant)]
const DOOR_OPEN_ANGLE: f64 = -1.5708;
/// This task's own target radius.
const RADIUS: f64 = 0.05;
const SUCCESS_DISTANCE: f64 = 0.08;

#[derive(Debug)]
struct DoorClose {
    door: usize,
    handle: usize,
    hinge_qpos: usize,
    hinge_dof: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let hinge = scene.sim.joint("doorjoint")?;
    Ok(Box::new(DoorClose {
        door: scene.sim.body("door")?,
        handle: scene.sim.geom("handle")?,
        hinge_qpos: scene.sim.jnt_qposadr(hinge),
        hinge_dof: scene.sim.jnt_dofadr(hinge),
    }))
}

impl Task for DoorClose {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = [
            rv[0] + GOAL_OFFSET[0],
            rv[1] + GOAL_OFFSET[1],
            rv[2] + GOAL_OFFSET[2],
        ];
        scene.sim.set_body_pos(self.door, scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        scene.set_scalar_joint(self.hinge_qpos, self.hinge_dof, DOOR_OPEN_ANGLE);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.geom_xpos(self.handle));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.handle)));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let target = scene.target_pos;
        let tcp_to_target = dist(scene.tcp_center(), target);
        let obj_to_target = dist(obj, target);

        let in_place = tolerance(
            obj_to_target,
            (0.0, RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::Gaussian,
        );
        let hand_margin = dist(scene.hand_init_pos, obj) + 0.1;
        let hand_in_place = tolerance(
            tcp_to_target,
            (0.0, 0.25 * RADIUS),
            hand_margin,
            Sigmoid::Gaussian,
        );
        let reward = if obj_to_target < RADIUS {
            10.0
        } else {
            3.0 * hand_in_place + 6.0 * in_place
        };
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_DISTANCE,
        }
    }
}
