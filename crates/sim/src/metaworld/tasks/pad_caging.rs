//! The `_gripper_caging_reward` override shared by push-back, soccer, sweep and sweep-into
//! (`metaworld/envs/sawyer_push_back_v3.py` and the others'): caging in y by both pads, caging
//! in x-z by the TCP, and a gripping term from the pads' y distance (the gripper effort is not
//! used). pick-place (`metaworld/envs/sawyer_pick_place_v3.py`) shares its caging part.

use crate::metaworld::reward::{dist_xz, hamacher_product, tolerance, Sigmoid};
use crate::metaworld::Scene;

const PAD_SUCCESS_MARGIN: f64 = 0.05;

/// The task-specific constants of the override.
#[derive(Debug, Clone, Copy)]
pub(super) struct PadCaging {
    /// The object's radius in y (lower bound of the caging and gripping ranges), m.
    pub obj_radius: f64,
    /// Upper bound of the gripping range: `obj_radius + grip_extra`, m.
    pub grip_extra: f64,
    /// x-z distance of TCP and object counted as caged, m.
    pub xz_success_margin: f64,
}

impl PadCaging {
    /// The caging part in [0, 1] (y caging by both pads, then x-z caging by the TCP) and the
    /// y gripping term for the object at `obj`. The pad margins use
    /// `init_left_pad`/`init_right_pad`, which in Python are live views of `data.xpos`: the
    /// current pad positions.
    pub fn caging(&self, scene: &Scene, obj: [f64; 3]) -> (f64, f64) {
        let tcp = scene.tcp_center();
        let left_pad = scene.left_pad_pos();
        let right_pad = scene.right_pad_pos();
        let delta_left = left_pad[1] - obj[1];
        let delta_right = obj[1] - right_pad[1];
        let right_margin = ((obj[1] - right_pad[1]).abs() - PAD_SUCCESS_MARGIN).abs();
        let left_margin = ((obj[1] - left_pad[1]).abs() - PAD_SUCCESS_MARGIN).abs();
        let caging_bounds = (self.obj_radius, PAD_SUCCESS_MARGIN);
        let grip_bounds = (self.obj_radius, self.obj_radius + self.grip_extra);
        let right_caging = tolerance(delta_right, caging_bounds, right_margin, Sigmoid::LongTail);
        let left_caging = tolerance(delta_left, caging_bounds, left_margin, Sigmoid::LongTail);
        let right_gripping = tolerance(delta_right, grip_bounds, right_margin, Sigmoid::LongTail);
        let left_gripping = tolerance(delta_left, grip_bounds, left_margin, Sigmoid::LongTail);
        let y_caging = hamacher_product(right_caging, left_caging);
        let y_gripping = hamacher_product(right_gripping, left_gripping);

        let xz_margin = dist_xz(scene.obj_init_pos, scene.init_tcp) - self.xz_success_margin;
        let xz_caging = tolerance(
            dist_xz(tcp, obj),
            (0.0, self.xz_success_margin),
            xz_margin,
            Sigmoid::LongTail,
        );
        (hamacher_product(y_caging, xz_caging), y_gripping)
    }

    /// Reward in [0, 1] for caging (and gripping) the object at `obj`.
    pub fn reward(&self, scene: &Scene, obj: [f64; 3]) -> f64 {
        let (caging, y_gripping) = self.caging(scene, obj);
        let gripping = if caging > 0.95 { y_gripping } else { 0.0 };
        (caging + gripping) / 2.0
    }
}
