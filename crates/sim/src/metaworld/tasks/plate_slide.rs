//! plate-slide-v3 (`metaworld/envs/sawyer_plate_slide_v3.py`): slide a puck across the table
//! into a goal.
//!
//! The body of the four plate-slide tasks: plate-slide-back, -side and -back-side build it
//! with their own [`Variant`].

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM, TARGET_RADIUS};

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

const VARIANT: Variant = Variant {
    puck_goal: PuckGoal::AtGoal,
    puck_joints: [0.0, 0.0],
    reward: Reward::Slide,
};

/// The puck's two slide joints (`qpos[9..11]`).
const PUCK_QPOS: std::ops::Range<usize> = 9..11;
const SUCCESS_RADIUS: f64 = 0.07;

/// What differs between the plate-slide tasks.
#[derive(Debug)]
pub(super) struct Variant {
    /// Where the reset moves the `puck_goal` body (the cabinet marker).
    pub puck_goal: PuckGoal,
    /// The puck's slide joints after the reset.
    pub puck_joints: [f64; 2],
    /// The reward's shape.
    pub reward: Reward,
}

/// Where the reset moves the `puck_goal` body.
#[derive(Debug)]
pub(super) enum PuckGoal {
    /// To the goal (plate-slide).
    AtGoal,
    /// To the puck's start (plate-slide-back-side: Python writes `obj_init_pos` there).
    AtStart,
    /// Nowhere: Python writes `data.body("puck_goal").xpos`, which the next `mj_forward`
    /// overwrites, so the marker stays where the model has it.
    Unmoved,
}

/// The reward's shape.
#[derive(Debug)]
pub(super) enum Reward {
    /// plate-slide's: `8 × hamacher(reach, in place)`, 10 inside the target radius.
    Slide,
    /// plate-slide-back's, -side's and -back-side's: 1.5 × reach reward, `2 + 7 × in-place`
    /// once the TCP is low (z ≤ 0.03) and within 7 cm of the puck, 10 inside the target
    /// radius.
    LowPush,
}

#[derive(Debug)]
struct PlateSlide {
    spec: &'static TaskSpec,
    variant: &'static Variant,
    puck: usize,
    puck_goal: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, &VARIANT)
}

/// A plate-slide task with another layout and variant.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    variant: &'static Variant,
) -> Result<Box<dyn Task>> {
    Ok(Box::new(PlateSlide {
        spec,
        variant,
        puck: scene.sim.geom("puck")?,
        puck_goal: scene.sim.body("puck_goal")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

/// plate-slide's reward and success.
fn slide_eval(scene: &Scene, obs: &[f64; OBS_DIM]) -> Eval {
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

/// The reward and success of plate-slide-back, -side and -back-side (see [`Reward::LowPush`]).
fn low_push_eval(scene: &Scene, obs: &[f64; OBS_DIM]) -> Eval {
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

impl Task for PlateSlide {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = [rv[3], rv[4], rv[5]];
        match self.variant.puck_goal {
            PuckGoal::AtGoal => scene.sim.set_body_pos(self.puck_goal, scene.target_pos),
            PuckGoal::AtStart => scene.sim.set_body_pos(self.puck_goal, scene.obj_init_pos),
            PuckGoal::Unmoved => {}
        }
        // The task's `_set_obj_xyz`: the puck's joints, velocities untouched, mj_forward.
        let mut qpos = scene.sim.qpos().to_vec();
        let qvel = scene.sim.qvel().to_vec();
        qpos[PUCK_QPOS].copy_from_slice(&self.variant.puck_joints);
        scene.set_state(&qpos, &qvel);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.geom_xpos(self.puck));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.puck)));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        match self.variant.reward {
            Reward::Slide => slide_eval(scene, obs),
            Reward::LowPush => low_push_eval(scene, obs),
        }
    }
}
