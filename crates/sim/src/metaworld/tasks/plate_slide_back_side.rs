//! plate-slide-back-side-v3: slide a puck out of the side cabinet (towards +x) into a goal.

use super::plate_slide_back::{low_push_eval, puck_objects, set_puck_joints};
use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "plate-slide-back-side-v3",
    xml: "sawyer_xyz/sawyer_plate_slide_sideway.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    // Python declares it as float32.
    hand_init_pos: [0.0, 0.6f32 as f64, 0.2f32 as f64],
    rand_low: &[-0.25, 0.6, 0.0, -0.05, 0.6, 0.015],
    rand_high: &[-0.25, 0.6, 0.0, 0.15, 0.6, 0.015],
    goal_low: [-0.05, 0.6, 0.015],
    goal_high: [0.15, 0.6, 0.015],
    rand_vec_ok: always_ok,
};

#[derive(Debug)]
struct PlateSlideBackSide {
    puck: usize,
    puck_goal: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    Ok(Box::new(PlateSlideBackSide {
        puck: scene.sim.geom("puck")?,
        puck_goal: scene.sim.body("puck_goal")?,
        goal_site: scene.sim.site("goal")?,
    }))
}

impl Task for PlateSlideBackSide {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.target_pos = [rv[3], rv[4], rv[5]];
        // The cabinet marker goes to the puck's start (Python writes obj_init_pos here).
        scene.sim.set_body_pos(self.puck_goal, scene.obj_init_pos);
        set_puck_joints(scene, [-0.15, 0.0]);
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        puck_objects(scene, self.puck, out);
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        low_push_eval(scene, obs)
    }
}
