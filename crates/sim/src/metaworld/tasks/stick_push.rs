//! stick-push-v3: grasp a stick and push a container with it towards a goal.

use super::{obj_goal_apart, TaskSpec};
use crate::error::Result;
use crate::metaworld::reward::{add, dist, scipy_quat_from_mat, tolerance, Sigmoid};
use crate::metaworld::{Density, Eval, Scene, Task, ACTION_DIM, OBS_DIM};

pub const SPEC: TaskSpec = TaskSpec {
    name: "stick-push-v3",
    xml: "sawyer_xyz/sawyer_stick_obj.xml",
    hand_low: [-0.5, 0.40, 0.05],
    hand_high: [0.5, 1.0, 0.5],
    mocap_low: None,
    mocap_high: None,
    hand_init_pos: [0.0, 0.6, 0.2],
    rand_low: &[-0.08, 0.58, 0.0, 0.399, 0.55, 0.1319],
    rand_high: &[-0.03, 0.62, 0.001, 0.401, 0.6, 0.1321],
    goal_low: [0.399, 0.55, 0.1319],
    goal_high: [0.401, 0.6, 0.1321],
    rand_vec_ok: obj_goal_apart::<10>,
};

/// The stick's height at reset (`init_config["stick_init_pos"][2]`), m.
pub(super) const STICK_Z: f64 = 0.02;
/// The task's `_TARGET_RADIUS`, m.
const TARGET_RADIUS: f64 = 0.12;

/// Model elements both stick tasks read.
#[derive(Debug)]
pub(super) struct StickScene {
    pub stick: usize,
    pub container: usize,
    pub insertion: usize,
}

impl StickScene {
    pub fn new(scene: &Scene) -> Result<Self> {
        Ok(Self {
            stick: scene.sim.body("stick")?,
            container: scene.sim.body("object")?,
            insertion: scene.sim.site("insertion")?,
        })
    }

    /// Python's reset after the hand reset: `_set_stick_xyz(stick)` (free joint `qpos[9..12]`,
    /// `qvel[9..15] = 0`, mj_forward), then `_set_obj_xyz(container_qpos)` (the container's
    /// two slide joints `qpos[16..18]`, `qvel[16..18]` zeroed as far as it exists, mj_forward). Returns the
    /// container's body position afterwards.
    pub fn place(&self, scene: &mut Scene, stick: [f64; 3], container_qpos: [f64; 2]) -> [f64; 3] {
        scene.set_obj_xyz(stick);
        let mut qpos = scene.sim.qpos().to_vec();
        let mut qvel = scene.sim.qvel().to_vec();
        qpos[16..18].copy_from_slice(&container_qpos);
        // Python writes `qvel[16:18] = 0` on 17 velocities: only `qvel[16]` (the y slide) is
        // zeroed; the x slide's velocity is `qvel[15]`.
        let end = qvel.len().min(18);
        qvel[16..end].fill(0.0);
        scene.set_state(&qpos, &qvel);
        scene.body_com(self.container)
    }

    /// obs[4..18]: stick position, the insertion site shifted by `insertion_offset`, the
    /// stick's scipy quaternion (x, y, z, w) and four zeros.
    pub fn objects(&self, scene: &Scene, insertion_offset: [f64; 3], out: &mut [f64; 14]) {
        out[..3].copy_from_slice(&scene.body_com(self.stick));
        out[3..7].copy_from_slice(&scipy_quat_from_mat(scene.sim.body_xmat(self.stick)));
        out[7..10].copy_from_slice(&add(scene.sim.site_xpos(self.insertion), insertion_offset));
        out[10..14].fill(0.0);
    }
}

#[derive(Debug)]
struct StickPush {
    parts: StickScene,
    /// The container's body position at reset (Python's `obj_init_pos`). `scene.obj_init_pos`
    /// holds the stick's start instead: the task's caging reward is measured from it.
    container_init_pos: [f64; 3],
    left_pad_geom: i32,
    right_pad_geom: i32,
    stick_geom: i32,
}

pub fn build(scene: &Scene) -> Result<Box<dyn Task>> {
    let geom = |name: &str| -> Result<i32> {
        Ok(i32::try_from(scene.sim.geom(name)?).expect("geom ids fit in i32"))
    };
    Ok(Box::new(StickPush {
        parts: StickScene::new(scene)?,
        container_init_pos: [0.0; 3],
        left_pad_geom: geom("leftpad_geom")?,
        right_pad_geom: geom("rightpad_geom")?,
        stick_geom: geom("objGeom")?,
    }))
}

/// Container-to-goal distance of success, m.
const SUCCESS_RADIUS: f64 = 0.12;

impl StickPush {
    /// Gripper open and the stick lifted 1 cm above its start (contacts aside).
    fn held(&self, scene: &Scene, obs: &[f64; OBS_DIM]) -> bool {
        obs[3] > 0.0 && obs[6] - 0.01 > scene.obj_init_pos[2]
    }

    /// Python's `touching_main_object`: both pads press on the stick (positive summed normal
    /// force over their contacts with it). A contact outside the constraint set has address
    /// -1, which Python's indexing reads as the last constraint force.
    fn touching_stick(&self, scene: &Scene) -> bool {
        let forces = scene.sim.efc_force();
        let force_of = |address: i32| -> f64 {
            match usize::try_from(address) {
                Ok(a) => forces[a],
                Err(_) => forces.last().copied().unwrap_or(0.0),
            }
        };
        let pad_force = |pad: i32| -> f64 {
            scene
                .sim
                .contacts()
                .filter(|c| {
                    (c.geom1 == pad || c.geom2 == pad)
                        && (c.geom1 == self.stick_geom || c.geom2 == self.stick_geom)
                })
                .map(|c| force_of(c.efc_address))
                .sum()
        };
        0.0 < pad_force(self.left_pad_geom) && 0.0 < pad_force(self.right_pad_geom)
    }
}

impl Task for StickPush {
    fn spec(&self) -> &'static TaskSpec {
        &SPEC
    }

    fn reset_model(&mut self, scene: &mut Scene, rv: &[f64]) -> Result<()> {
        scene.reset_hand();
        let stick_init = [rv[0], rv[1], STICK_Z];
        // The goal's height is the insertion site's before the stick and container are placed.
        let insertion_z = scene.sim.site_xpos(self.parts.insertion)[2];
        scene.target_pos = [rv[3], rv[4], insertion_z];
        self.container_init_pos = self.parts.place(scene, stick_init, [0.0, 0.0]);
        scene.obj_init_pos = stick_init;
        scene.set_site_pos("goal", scene.target_pos)?;
        Ok(())
    }

    fn objects(&self, scene: &Scene, out: &mut [f64; 14]) {
        self.parts.objects(scene, [0.0, 0.09, 0.0], out);
    }

    fn reads_contacts(&self, scene: &Scene, obs: &[f64; OBS_DIM]) -> bool {
        // `evaluate` reads contact forces only when the rest of its success rule holds.
        let container = [obs[11], obs[12], obs[13]];
        self.held(scene, obs) && dist(container, scene.target_pos) <= SUCCESS_RADIUS
    }

    fn evaluate(
        &mut self,
        scene: &Scene,
        obs: &[f64; OBS_DIM],
        action: &[f32; ACTION_DIM],
    ) -> Eval {
        let stick_init = scene.obj_init_pos;
        let stick = [obs[4] + 0.015, obs[5], obs[6]];
        let container = [obs[11], obs[12], obs[13]];
        let tcp_opened = obs[3];
        let target = scene.target_pos;
        let tcp_to_stick = dist(stick, scene.tcp_center());
        let stick_in_place = tolerance(
            dist(stick, target),
            (0.0, TARGET_RADIUS),
            dist(stick_init, target) - TARGET_RADIUS,
            Sigmoid::LongTail,
        );
        let container_to_target = dist(container, target);
        let container_in_place = tolerance(
            container_to_target,
            (0.0, TARGET_RADIUS),
            dist(self.container_init_pos, target) - TARGET_RADIUS,
            Sigmoid::LongTail,
        );
        let object_grasped =
            scene.gripper_caging_reward(action, stick, 0.04, 0.05, 0.01, 0.01, 1.0, Density::High);
        let mut reward = object_grasped;
        if tcp_to_stick < 0.02 && tcp_opened > 0.0 && stick[2] - 0.01 > stick_init[2] {
            reward = 2.0 + 5.0 * stick_in_place + 3.0 * container_in_place;
            if container_to_target <= TARGET_RADIUS {
                reward = 10.0;
            }
        }
        // Success needs the stick held (contact on both pads, gripper open > 0, lifted by 1 cm)
        // and the container within 12 cm of the goal.
        let success = container_to_target <= SUCCESS_RADIUS
            && self.held(scene, obs)
            && self.touching_stick(scene);
        Eval { reward, success }
    }
}
