//! door-open-v3 (`metaworld/envs/sawyer_door_v3.py`): pull a hinged door open by its handle.
//!
//! The body of both door tasks: door-close builds it with its own [`Variant`].

use std::f64::consts::PI;

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{
    hamacher_product, norm, norm2, scipy_quat_from_mat, sub, tolerance, Sigmoid,
};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "door-open-v3",
    xml: "sawyer_xyz/sawyer_door_pull.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[0.0, 0.85, 0.15],
    rand_high: &[0.1, 0.95, 0.15],
    goal_low: [-0.3, 0.4, 0.1499],
    goal_high: [-0.2, 0.5, 0.1501],
    rand_vec_ok: always_ok,
};

/// Goal relative to the door position.
const GOAL_OFFSET: [f64; 3] = [-0.3, -0.45, 0.0];
/// Success: the handle's x within this distance of the goal's.
const SUCCESS_X_DIST: f64 = 0.08;

const VARIANT: Variant = Variant {
    goal_offset: GOAL_OFFSET,
    // `_set_obj_xyz(0)`: close the door.
    hinge_angle: 0.0,
    evaluate,
};

/// What differs between door-open and door-close.
#[derive(Debug)]
pub(super) struct Variant {
    /// Goal relative to the door position.
    pub goal_offset: [f64; 3],
    /// Hinge angle the reset puts the door at (`_set_obj_xyz`).
    pub hinge_angle: f64,
    /// The task's reward and success, also given the hinge angle.
    pub evaluate: fn(&Scene, f64, &[f64; OBS_DIM], &[f32; ACTION_DIM]) -> Eval,
}

#[derive(Debug)]
struct Door {
    spec: &'static TaskSpec,
    variant: &'static Variant,
    door: usize,
    handle: usize,
    hinge_qpos: usize,
    hinge_dof: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, &VARIANT)
}

/// A door task with another layout and variant.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    variant: &'static Variant,
) -> Result<Box<dyn Task>> {
    let hinge = scene.sim.joint("doorjoint")?;
    Ok(Box::new(Door {
        spec,
        variant,
        door: scene.sim.body("door")?,
        handle: scene.sim.geom("handle")?,
        hinge_qpos: scene.sim.jnt_qposadr(hinge),
        hinge_dof: scene.sim.jnt_dofadr(hinge),
    }))
}

/// `_reward_grab_effort`: the gripper effort mapped to [0, 1], in `f32` as NumPy computes it.
fn grab_effort(action: &[f32; ACTION_DIM]) -> f64 {
    f64::from((action[3].clamp(-1.0, 1.0) + 1.0) / 2.0)
}

/// `_reward_pos`: (ready to open, opened) from the hand/handle positions and the hinge angle.
fn reward_pos(obs: &[f64; OBS_DIM], theta: f64) -> (f64, f64) {
    let hand = [obs[0], obs[1], obs[2]];
    let door = [obs[4] - 0.05, obs[5], obs[6]];
    let threshold = 0.12;
    // A funnel around the handle keeps the hand from running into it prematurely.
    let radius = norm2(sub(hand, door));
    let floor = if radius <= threshold {
        0.0
    } else {
        0.04 * (radius - threshold).ln() + 0.4
    };
    let above_floor = if hand[2] >= floor {
        1.0
    } else {
        tolerance(floor - hand[2], (0.0, 0.01), floor / 2.0, Sigmoid::LongTail)
    };
    let hand_offset = [
        hand[0] - door[0] - 0.05,
        hand[1] - door[1] - 0.03,
        hand[2] - door[2] - -0.01,
    ];
    let in_place = tolerance(
        norm(hand_offset),
        (0.0, threshold / 2.0),
        0.5,
        Sigmoid::LongTail,
    );
    let ready_to_open = hamacher_product(above_floor, in_place);

    let door_angle = -theta;
    let tried = if theta < -PI / 90.0 { 1.0 } else { 0.0 };
    let opened = 0.2 * tried
        + 0.8
            * tolerance(
                PI / 2.0 + PI / 6.0 - door_angle,
                (0.0, 0.5),
                PI / 3.0,
                Sigmoid::LongTail,
            );
    (ready_to_open, opened)
}

/// door-open's reward and success.
fn evaluate(scene: &Scene, theta: f64, obs: &[f64; OBS_DIM], action: &[f32; ACTION_DIM]) -> Eval {
    let grab = grab_effort(action);
    let (ready, opened) = reward_pos(obs, theta);
    let success = (obs[4] - scene.target_pos[0]).abs() <= SUCCESS_X_DIST;
    let reward = if success {
        10.0
    } else {
        2.0 * hamacher_product(ready, grab) + 8.0 * opened
    };
    Eval { reward, success }
}

impl Task for Door {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        let goal_offset = self.variant.goal_offset;
        scene.target_pos = std::array::from_fn(|i| rv[i] + goal_offset[i]);
        scene.sim.set_body_pos(self.door, scene.obj_init_pos);
        scene.set_site_pos("goal", scene.target_pos)?;
        let angle = self.variant.hinge_angle;
        scene.set_scalar_joint(self.hinge_qpos, self.hinge_dof, angle);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.geom_xpos(self.handle));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.handle)));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let theta = scene.sim.qpos()[self.hinge_qpos];
        (self.variant.evaluate)(scene, theta, obs, action)
    }
}
