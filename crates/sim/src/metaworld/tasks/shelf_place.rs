//! shelf-place-v3: pick a block up and place it on a shelf.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{
    add, dist, hamacher_product, scipy_quat_from_mat, tolerance, Sigmoid,
};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "shelf-place-v3",
    xml: "sawyer_xyz/sawyer_shelf_placing.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // Python declares it as float32.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.1, 0.5, 0.019, -0.1, 0.8, 0.299],
    rand_high: &[0.1, 0.6, 0.021, 0.1, 0.9, 0.301],
    goal_low: [-0.1, 0.8, 0.299],
    goal_high: [0.1, 0.9, 0.301],
    rand_vec_ok: obj_goal_apart::<10>,
};

/// The shelf body sits this far below the sampled goal.
const SHELF_BELOW_GOAL: f64 = 0.3;
const TARGET_RADIUS: f64 = 0.05;
const SUCCESS_RADIUS: f64 = 0.07;
/// Height of the shelf's front region where the block is penalised for being below it.
const SHELF_ZONE_HEIGHT: f64 = 0.24;
/// Half-width (x) of the shelf region.
const SHELF_ZONE_HALF_WIDTH: f64 = 0.15;

#[derive(Debug)]
struct ShelfPlace {
    obj: usize,
    obj_geom: usize,
    shelf: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(ShelfPlace {
        obj: scene.sim.body("obj")?,
        obj_geom: scene.sim.geom("objGeom")?,
        shelf: scene.sim.body("shelf")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

impl Task for ShelfPlace {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        // `adjust_initObjPos` only contributes the block's settled height.
        let height = scene.body_com(self.obj)[2];
        scene.obj_init_pos = [rv[0], rv[1], height];
        let shelf_pos = [rv[3], rv[4], rv[5] - SHELF_BELOW_GOAL];
        scene.sim.set_body_pos(self.shelf, shelf_pos);
        scene.forward();
        scene.target_pos = add(scene.sim.site_pos(self.goal_site), shelf_pos);
        scene.set_obj_xyz(scene.obj_init_pos);
        // `_set_pos_site("goal", ...)` writes data.site_xpos, which nothing reads before the
        // next kinematics pass overwrites it.
        scene.sim.set_site_xpos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.obj));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.obj_geom)));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let tcp_opened = obs[3];
        let target = scene.target_pos;
        let obj_to_target = dist(obj, target);
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let mut in_place = tolerance(
            obj_to_target,
            (0.0, TARGET_RADIUS),
            dist(scene.obj_init_pos, target),
            Sigmoid::LongTail,
        );
        let object_grasped =
            scene.gripper_caging_reward(action, obj, 0.02, 0.05, 0.01, 0.01, 1.0, Density::Normal);
        let mut reward = hamacher_product(object_grasped, in_place);

        let below_shelf_top = 0.0 < obj[2] && obj[2] < SHELF_ZONE_HEIGHT;
        let within_shelf_x = target[0] - SHELF_ZONE_HALF_WIDTH < obj[0]
            && obj[0] < target[0] + SHELF_ZONE_HALF_WIDTH;
        let front_depth = 3.0 * TARGET_RADIUS;
        if below_shelf_top
            && within_shelf_x
            && target[1] - front_depth < obj[1]
            && obj[1] < target[1]
        {
            let z_scaling = (SHELF_ZONE_HEIGHT - obj[2]) / SHELF_ZONE_HEIGHT;
            let y_scaling = (obj[1] - (target[1] - front_depth)) / front_depth;
            let bound_loss = hamacher_product(y_scaling, z_scaling);
            in_place = (in_place - bound_loss).clamp(0.0, 1.0);
        }
        if below_shelf_top && within_shelf_x && obj[1] > target[1] {
            in_place = 0.0;
        }
        if tcp_to_obj < 0.025 && tcp_opened > 0.0 && obj[2] - 0.01 > scene.obj_init_pos[2] {
            reward += 1.0 + 5.0 * in_place;
        }
        if obj_to_target < TARGET_RADIUS {
            reward = 10.0;
        }
        Eval {
            reward,
            success: obj_to_target <= SUCCESS_RADIUS,
        }
    }
}
