//! peg-insert-side-v3: pick up a peg and insert it sideways into a hole in a box.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{
    dist, hamacher_product, rect_prism_tolerance, scaled_dist, scipy_quat_from_mat, tolerance,
    Sigmoid,
};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

/// Goal (inside the hole) relative to the box position.
const GOAL_OFFSET: [f64; 3] = [0.03, 0.0, 0.13];
const BOX_LOW: [f64; 3] = [-0.35, 0.4, -0.001];
const BOX_HIGH: [f64; 3] = [-0.25, 0.7, 0.001];

pub const SPEC: TaskSpec = TaskSpec {
    name: "peg-insert-side-v3",
    xml: "sawyer_xyz/sawyer_peg_insertion_side.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[0.0, 0.5, 0.02, BOX_LOW[0], BOX_LOW[1], BOX_LOW[2]],
    rand_high: &[0.2, 0.7, 0.02, BOX_HIGH[0], BOX_HIGH[1], BOX_HIGH[2]],
    goal_low: [
        BOX_LOW[0] + GOAL_OFFSET[0],
        BOX_LOW[1] + GOAL_OFFSET[1],
        BOX_LOW[2] + GOAL_OFFSET[2],
    ],
    goal_high: [
        BOX_HIGH[0] + GOAL_OFFSET[0],
        BOX_HIGH[1] + GOAL_OFFSET[1],
        BOX_HIGH[2] + GOAL_OFFSET[2],
    ],
    rand_vec_ok: obj_goal_apart::<10>,
};

/// Caging reward parameters of the peg.
const PAD_SUCCESS_MARGIN: f64 = 0.03;
const OBJECT_REACH_RADIUS: f64 = 0.01;
const XZ_MARGIN: f64 = 0.005;
const OBJ_RADIUS: f64 = 0.0075;
/// The peg head's distance to the goal weighs y and z double.
const HEAD_ERROR_SCALE: [f64; 3] = [1.0, 2.0, 2.0];
/// The task's own `TARGET_RADIUS` (the class attribute overrides the base 0.05).
const TARGET_RADIUS: f64 = 0.07;
/// Success: the scaled head-to-goal distance at most this.
const SUCCESS_DIST: f64 = 0.07;

#[derive(Debug)]
struct PegInsertSide {
    box_body: usize,
    peg_grasp: usize,
    peg_head: usize,
    /// (bottom-right, top-left) corner sites of the two collision boxes around the hole.
    collision_boxes: [(usize, usize); 2],
    /// `peg_head_pos_init`: read before the peg is placed.
    peg_head_pos_init: [f64; 3],
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let corners = |i: u32| -> Result<(usize, usize)> {
        Ok((
            scene
                .sim
                .site(&format!("bottom_right_corner_collision_box_{i}"))?,
            scene
                .sim
                .site(&format!("top_left_corner_collision_box_{i}"))?,
        ))
    };
    Ok(Box::new(PegInsertSide {
        box_body: scene.sim.body("box")?,
        peg_grasp: scene.sim.site("pegGrasp")?,
        peg_head: scene.sim.site("pegHead")?,
        collision_boxes: [corners(1)?, corners(2)?],
        peg_head_pos_init: [0.0; 3],
    }))
}

impl Task for PegInsertSide {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let pos_box = [rv[3], rv[4], rv[5]];
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        self.peg_head_pos_init = scene.sim.site_xpos(self.peg_head);
        scene.set_obj_xyz(scene.obj_init_pos);
        scene.sim.set_body_pos(self.box_body, pos_box);
        scene.target_pos = std::array::from_fn(|i| pos_box[i] + GOAL_OFFSET[i]);
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.sim.site_xpos(self.peg_grasp));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.site_xmat(self.peg_grasp)));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let obj_head = scene.sim.site_xpos(self.peg_head);
        let tcp_opened = obs[3];
        let target = scene.target_pos;
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let obj_to_target = scaled_dist(obj_head, target, HEAD_ERROR_SCALE);
        let in_place_margin = scaled_dist(self.peg_head_pos_init, target, HEAD_ERROR_SCALE);
        let in_place = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            in_place_margin,
            Sigmoid::LongTail,
        );
        let [box1, box2] = self.collision_boxes.map(|(bottom_right, top_left)| {
            rect_prism_tolerance(
                obj_head,
                scene.sim.site_xpos(bottom_right),
                scene.sim.site_xpos(top_left),
            )
        });
        let in_place = hamacher_product(in_place, hamacher_product(box2, box1));

        let lifted = tcp_to_obj < 0.08 && tcp_opened > 0.0 && obj[2] - 0.01 > scene.obj_init_pos[2];
        let object_grasped = if lifted {
            1.0
        } else {
            scene.gripper_caging_reward(
                action,
                obj,
                OBJ_RADIUS,
                PAD_SUCCESS_MARGIN,
                OBJECT_REACH_RADIUS,
                XZ_MARGIN,
                1.0,
                Density::High,
            )
        };
        let mut reward = hamacher_product(object_grasped, in_place);
        if lifted {
            reward += 1.0 + 5.0 * in_place;
        }
        let success = obj_to_target <= SUCCESS_DIST;
        if success {
            reward = 10.0;
        }
        Eval { reward, success }
    }
}
