//! The body shared by the tasks around one puck-like object (`obj`, geom `objGeom`) and a goal
//! site: reach, reach-wall, push, push-wall, push-back, pick-place and pick-place-wall
//! (`metaworld/envs/sawyer_reach_v3.py`, `sawyer_push_v3.py`, … ). Their resets and
//! observations differ only in the few choices of [`Variant`]; each task keeps its own reward.

use crate::error::Result;
use crate::metaworld::reward::scipy_quat_from_mat;
use crate::metaworld::{Eval, Scene, Task, TaskSpec, ACTION_DIM, OBS_DIM};

/// A task's reward and success.
pub(super) type Evaluate = fn(&Scene, &[f64; OBS_DIM], &[f32; ACTION_DIM]) -> Eval;

/// What differs between the puck tasks.
#[derive(Debug)]
pub(super) struct Variant {
    /// The observed position is the `obj` body's centre of mass (`get_body_com("obj")`);
    /// else the `objGeom` geom's position.
    pub observe_body: bool,
    /// The puck's resting height after the hand reset (of the observed point) is both the
    /// object and the goal height (Python's `adjust_initObjPos` or `get_body_com`); else the
    /// heights come from `rand_vec`.
    pub resting_height: bool,
    /// The reset moves the goal site before placing the puck (push-wall); else after.
    pub goal_site_first: bool,
    /// The task's reward and success.
    pub evaluate: Evaluate,
}

#[derive(Debug)]
struct Puck {
    spec: &'static TaskSpec,
    variant: &'static Variant,
    /// The `obj` body, when observed.
    obj: Option<usize>,
    obj_geom: usize,
}

/// A puck task of this layout and variant.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    variant: &'static Variant,
) -> Result<Box<dyn Task>> {
    let obj = if variant.observe_body {
        Some(scene.sim.body("obj")?)
    } else {
        None
    };
    Ok(Box::new(Puck {
        spec,
        variant,
        obj,
        obj_geom: scene.sim.geom("objGeom")?,
    }))
}

impl Puck {
    fn position(&self, scene: &Scene) -> [f64; 3] {
        match self.obj {
            Some(obj) => scene.body_com(obj),
            None => scene.sim.geom_xpos(self.obj_geom),
        }
    }
}

impl Task for Puck {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        if self.variant.resting_height {
            let height = self.position(scene)[2];
            scene.target_pos = [rv[3], rv[4], height];
            scene.obj_init_pos = [rv[0], rv[1], height];
        } else {
            scene.target_pos = [rv[3], rv[4], rv[5]];
            scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        }
        // pick-place: Python re-reads `init_tcp` and the pad views here: no change in value.
        if self.variant.goal_site_first {
            scene.set_site_pos("goal", scene.target_pos)?;
            scene.set_obj_xyz(scene.obj_init_pos);
        } else {
            scene.set_obj_xyz(scene.obj_init_pos);
            scene.set_site_pos("goal", scene.target_pos)?;
        }
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&self.position(scene));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.geom_xmat(self.obj_geom)));
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        (self.variant.evaluate)(scene, obs, action)
    }
}
