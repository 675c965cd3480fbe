//! button-press-v3 (`metaworld/envs/sawyer_button_press_v3.py`): press a button on a
//! wall-mounted box horizontally (along +y).
//!
//! The body of all four button-press tasks: button-press-wall, button-press-topdown and
//! button-press-topdown-wall build this task with their own [`Variant`].

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{dist, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "button-press-v3",
    xml: "sawyer_xyz/sawyer_button_press.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // float32 in Python's init_config.
    hand_init_pos: [0.0, 0.4f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.85, 0.115],
    rand_high: &[0.1, 0.9, 0.115],
    goal_low: [-0.5, 0.40, 0.05],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

/// button-press-v3's variant.
const VARIANT: Variant = Variant {
    axis: 1,
    face_offset: -0.193,
    zero_button_joint: true,
    near_radius: 0.05,
    shaping: Shaping::Sum {
        closed: Closed::Clamped,
        approach: 2.0,
        press: 8.0,
        press_within: 0.05,
    },
    success_distance: 0.02,
};

/// The button's slide joint (`qpos[9]`, `qvel[9]` in Python).
const BUTTON_JOINT_ADR: usize = 9;

/// What differs between the four button-press tasks.
#[derive(Debug)]
pub(super) struct Variant {
    /// The axis the button moves along: 1 (y, pressed horizontally) or 2 (z, from above).
    pub axis: usize,
    /// From the button body to its pressing surface along `axis`.
    pub face_offset: f64,
    /// Whether the reset zeroes the button's slide joint (`_set_obj_xyz`); else it only runs
    /// a forward pass.
    pub zero_button_joint: bool,
    /// Upper bound of the hand-to-button distance counted as at the button (`near_button`).
    pub near_radius: f64,
    /// How the reward combines reaching and pressing.
    pub shaping: Shaping,
    /// Success: the button within this distance of the goal along `axis`.
    pub success_distance: f64,
}

/// The reward's shape.
#[derive(Debug)]
pub(super) enum Shaping {
    /// `approach · hamacher(closed, near_button)`, plus `press · button_pressed` once the hand
    /// is within `press_within` of the button.
    Sum {
        closed: Closed,
        approach: f64,
        press: f64,
        press_within: f64,
    },
    /// button-press-wall-v3's: beyond `far` only the approach (with the gripper's opening as
    /// `(1 − obs[3]) / 2`), within it `2 + 2 (1 + obs[3]) + 4 · button_pressed²`.
    Wall { far: f64 },
}

/// How the `tcp_closed` term reads the gripper opening `obs[3]`.
#[derive(Debug)]
pub(super) enum Closed {
    /// `max(obs[3], 0)`.
    Clamped,
    /// `1 − obs[3]`.
    Inverted,
}

#[derive(Debug)]
struct ButtonPress {
    spec: &'static TaskSpec,
    variant: &'static Variant,
    box_body: usize,
    button: usize,
    hole: usize,
    button_start: usize,
    /// Initial distance of button and goal along the axis (`_obj_to_target_init`).
    obj_to_target_init: f64,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, &VARIANT)
}

/// A button-press task with another layout and variant.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    variant: &'static Variant,
) -> Result<Box<dyn Task>> {
    Ok(Box::new(ButtonPress {
        spec,
        variant,
        box_body: scene.sim.body("box")?,
        button: scene.sim.body("button")?,
        hole: scene.sim.site("hole")?,
        button_start: scene.sim.site("buttonStart")?,
        obj_to_target_init: 0.0,
    }))
}

impl Task for ButtonPress {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        let axis = self.variant.axis;
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.box_body, scene.obj_init_pos);
        if self.variant.zero_button_joint {
            scene.set_scalar_joint(BUTTON_JOINT_ADR, BUTTON_JOINT_ADR, 0.0);
        } else {
            scene.forward();
        }
        scene.target_pos = scene.sim.site_xpos(self.hole);
        self.obj_to_target_init =
            (scene.target_pos[axis] - scene.sim.site_xpos(self.button_start)[axis]).abs();
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        let mut pos = scene.body_com(self.button);
        pos[self.variant.axis] += self.variant.face_offset;
        out[..3].copy_from_slice(&pos);
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.button));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let variant = self.variant;
        let obj = [obs[4], obs[5], obs[6]];
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let tcp_to_obj_init = dist(obj, scene.init_tcp);
        let obj_to_target = (scene.target_pos[variant.axis] - obj[variant.axis]).abs();

        let near_button = tolerance(
            tcp_to_obj,
            (0.0, variant.near_radius),
            tcp_to_obj_init,
            Sigmoid::LongTail,
        );
        let button_pressed = tolerance(
            obj_to_target,
            (0.0, 0.005),
            self.obj_to_target_init,
            Sigmoid::LongTail,
        );
        let reward = match variant.shaping {
            Shaping::Sum {
                ref closed,
                approach,
                press,
                press_within,
            } => {
                let tcp_closed = match closed {
                    Closed::Clamped => obs[3].max(0.0),
                    Closed::Inverted => 1.0 - obs[3],
                };
                let mut reward = approach * hamacher_product(tcp_closed, near_button);
                if tcp_to_obj <= press_within {
                    reward += press * button_pressed;
                }
                reward
            }
            Shaping::Wall { far } => {
                if tcp_to_obj > far {
                    let tcp_status = (1.0 - obs[3]) / 2.0;
                    2.0 * hamacher_product(tcp_status, near_button)
                } else {
                    2.0 + 2.0 * (1.0 + obs[3]) + 4.0 * button_pressed.powi(2)
                }
            }
        };
        Eval {
            reward,
            success: obj_to_target <= variant.success_distance,
        }
    }
}
