//! faucet-open-v3 (`metaworld/envs/sawyer_faucet_open_v3.py`): rotate the faucet handle to
//! the open side (+x).
//!
//! The body of both faucet tasks: faucet-close builds it with its own [`Variant`].

use super::{always_ok, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{add, dist, radius_tolerance, Sigmoid};
use crate::metaworld::{Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "faucet-open-v3",
    xml: "sawyer_xyz/sawyer_faucet.xml",
    hand_low: [-0.5, 0.40, -0.15],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.4, 0.2],
    rand_low: &[-0.05, 0.8, 0.0],
    rand_high: &[0.05, 0.85, 0.0],
    goal_low: [-0.5, 0.40, -0.15],
    goal_high: [0.5, 1.0, 0.5],
    rand_vec_ok: always_ok,
};

/// Length of the faucet handle: the goal sits at its tip when opened (or closed).
pub(super) const HANDLE_LENGTH: f64 = 0.175;
/// The observed handle point is this far below the handle site.
const HANDLE_OBS_OFFSET: [f64; 3] = [0.0, 0.0, -0.01];
const TARGET_RADIUS: f64 = 0.07;
const REACH_RADIUS: f64 = 0.01;

const VARIANT: Variant = Variant {
    handle_site: "handleStartOpen",
    goal_site: "goal_open",
    goal_offset: [HANDLE_LENGTH, 0.0, 0.125],
    forward_at_reset: false,
    reward_handle_offset: Some([-0.04, 0.0, 0.03]),
};

/// What differs between faucet-open and faucet-close.
#[derive(Debug)]
pub(super) struct Variant {
    /// The site observed as the handle.
    pub handle_site: &'static str,
    /// The goal's site.
    pub goal_site: &'static str,
    /// Goal offset from the faucet base.
    pub goal_offset: [f64; 3],
    /// Whether the reset ends with a kinematics pass (before the goal site moves).
    pub forward_at_reset: bool,
    /// The reward measures a point shifted from the observed handle position by this much.
    pub reward_handle_offset: Option<[f64; 3]>,
}

#[derive(Debug)]
struct Faucet {
    spec: &'static TaskSpec,
    variant: &'static Variant,
    base: usize,
    handle: usize,
    goal_site: usize,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    build_with(scene, &SPEC, &VARIANT)
}

/// A faucet task with another layout and variant.
pub(super) fn build_with(
    scene: &Scene,
    spec: &'static TaskSpec,
    variant: &'static Variant,
) -> Result<Box<dyn Task>> {
    Ok(Box::new(Faucet {
        spec,
        variant,
        base: scene.sim.body("faucetBase")?,
        handle: scene.sim.site(variant.handle_site)?,
        goal_site: scene.sim.site(variant.goal_site)?,
    }))
}

impl Task for Faucet {
    fn spec(&self) -> &'static TaskSpec {
        self.spec
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        scene.obj_init_pos = [rv[0], rv[1], rv[2]];
        scene.sim.set_body_pos(self.base, scene.obj_init_pos);
        scene.target_pos = add(scene.obj_init_pos, self.variant.goal_offset);
        if self.variant.forward_at_reset {
            scene.forward();
        }
        scene.sim.set_site_pos(self.goal_site, scene.target_pos);
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&add(scene.sim.site_xpos(self.handle), HANDLE_OBS_OFFSET));
        out[3..7].copy_from_slice(&scene.sim.body_xquat(self.base));
    }

    fn evaluate(&mut self, scene: &Scene, obs: &[f64; OBS_DIM], _a: &[f32; ACTION_DIM]) -> Eval {
        let obj = [obs[4], obs[5], obs[6]];
        let obj = match self.variant.reward_handle_offset {
            Some(offset) => add(obj, offset),
            None => obj,
        };
        let target_to_obj = dist(obj, scene.target_pos);
        let target_to_obj_init = dist(scene.obj_init_pos, scene.target_pos);
        let in_place = radius_tolerance(
            target_to_obj,
            TARGET_RADIUS,
            target_to_obj_init,
            Sigmoid::LongTail,
        );
        let tcp_to_obj = dist(obj, scene.tcp_center());
        let tcp_to_obj_init = dist(scene.obj_init_pos, scene.init_tcp);
        let reach = radius_tolerance(tcp_to_obj, REACH_RADIUS, tcp_to_obj_init, Sigmoid::Gaussian);
        let success = target_to_obj <= TARGET_RADIUS;
        let reward = if success {
            10.0
        } else {
            2.0 * (2.0 * reach + 3.0 * in_place)
        };
        Eval { reward, success }
    }
}
