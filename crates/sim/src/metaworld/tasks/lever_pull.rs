//! lever-pull-v3: pull a lever up until it points straight upward.

use std::f64::consts::PI;

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{add, dist, hamacher_product, norm, scipy_quat_from_mat, sub};
use crate::metaworld::reward::{tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "lever-pull-v3",
    xml: "sawyer_xyz/sawyer_lever_pull.xml",
    hand_low: [-0.5, 0.40, -0.15],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // Python declares it as float32.
    hand_init_pos: [0.0, 0.4f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.7, 0.0],
    rand_high: &[0.1, 0.8, 0.0],
    goal_low: [-0.5, 0.40, -0.15],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

const LEVER_RADIUS: f64 = 0.2;
/// Lever tip at rest, relative to the lever base.
const LEVER_TIP_OFFSET: [f64; 3] = [0.12, -LEVER_RADIUS, 0.25];
/// Lever tip pointing up (the goal), relative to the lever base.
const GOAL_OFFSET: [f64; 3] = [0.12, 0.0, 0.25 + LEVER_RADIUS];
/// Offset from the hand to the Sawyer's "shoulder" that should get under the lever.
const SHOULDER_OFFSET: [f64; 3] = [0.0, 0.055, 0.07];
/// Per-axis weights of the shoulder-to-lever error (y de-emphasised).
const SHOULDER_SCALE: [f64; 3] = [4.0, 1.0, 4.0];

#[derive(Debug)]
struct LeverPull {
    lever: usize,
    lever_start: usize,
    obj_geom: usize,
    goal_site: usize,
    lever_axis_qpos: usize,
    /// Lever tip position at reset (`_lever_pos_init`).
    lever_pos_init: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let axis = scene.sim.joint("LeverAxis")?;
    Ok(Box::new(LeverPull {
        lever: scene.sim.body("lever")?,
        lever_start: scene.sim.site("leverStart")?,
        obj_geom: scene.sim.geom("objGeom")?,
        goal_site: scene.sim.site("goal")?,
        lever_axis_qpos: scene.sim.jnt_qposadr(axis),
        lever_pos_init: [0.0; 3],
    }))
}

/// `(hand + SHOULDER_OFFSET - lever) * SHOULDER_SCALE`.
fn shoulder_to_lever(hand: [f64; 3], lever: [f64; 3]) -> [f64; 3] {
    let d = sub(add(hand, SHOULDER_OFFSET), lever);
    [
        d[0] * SHOULDER_SCALE[0],
        d[1] * SHOULDER_SCALE[1],
        d[2] * SHOULDER_SCALE[2],
    ]
}

impl Task for LeverPull {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.lever, scene.obj_init_pos);
        self.lever_pos_init = add(scene.obj_init_pos, LEVER_TIP_OFFSET);
        scene.target_pos = add(scene.obj_init_pos, GOAL_OFFSET);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.lever_start));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.obj_geom)));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let gripper = [obs[0], obs[1], obs[2]];
        let lever = [obs[4], obs[5], obs[6]];
        let ready_to_lift = tolerance(
            norm(shoulder_to_lever(gripper, lever)),
            (0.0, 0.02),
            norm(shoulder_to_lever(scene.init_tcp, self.lever_pos_init)),
            Sigmoid::LongTail,
        );
        let lever_angle = -scene.sim.qpos()[self.lever_axis_qpos];
        let lever_error = (lever_angle - PI / 2.0).abs();
        let target = scene.target_pos;
        let in_place = tolerance(
            dist(lever, target),
            (0.0, 0.04),
            dist(self.lever_pos_init, target),
            Sigmoid::LongTail,
        );
        Eval {
            reward: 10.0 * hamacher_product(ready_to_lift, in_place),
            success: lever_error <= PI / 24.0,
        }
    }
}
