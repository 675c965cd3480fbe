//! Meta-World's scripted expert policies (`metaworld.policies`, v3), ported to Rust.
//!
//! Each policy is a pure function of the 39-dim observation: a small state machine over the hand
//! position (`obs[0..3]`), the gripper opening (`obs[3]`), the first object's position (`obs[4..7]`)
//! and the goal (obs[36..39]). Like the Python policies, the returned xyz components are the
//! unclipped `p * (target - hand)` (the environment clips them to [-1, 1]); the values equal
//! Python's float32 action for the same observation.
//!
//! ```no_run
//! # use terl_sim::metaworld::{policies, Env};
//! let mut env = Env::new("reach-v3")?;
//! let policy = policies::policy("reach-v3")?;
//! let mut obs = env.reset_variation(0, 0)?;
//! for _ in 0..500 {
//!     let step = env.step(&policy(&obs))?;
//!     obs = step.obs;
//!     if step.success { break; }
//! }
//! # Ok::<(), terl_sim::SimError>(())
//! ```

use super::{ACTION_DIM, OBS_DIM};
use crate::error::{Result, SimError};

mod button_press;
mod button_press_topdown;
mod coffee_button;
mod dial_turn;
mod door_close;
mod door_lock;
mod door_open;
mod door_unlock;
mod drawer_close;
mod drawer_open;
mod faucet_close;
mod faucet_open;
mod handle_press;
mod lever_pull;
mod peg_insert_side;
mod peg_unplug_side;
mod pick_out_of_hole;
mod pick_place;
mod pick_place_wall;
mod plate_slide;
mod plate_slide_back;
mod plate_slide_back_side;
mod plate_slide_side;
mod push;
mod push_back;
mod push_wall;
mod reach;
mod reach_wall;
mod shelf_place;
mod soccer;
mod stick_pull;
mod stick_push;
mod sweep;
mod sweep_into;
mod window_close;
mod window_open;

// MT50 tasks, part A.
mod assembly;
mod basketball;
mod bin_picking;
mod box_close;
mod button_press_topdown_wall;
mod button_press_wall;
mod coffee_pull;
mod coffee_push;
mod disassemble;
mod hammer;
mod hand_insert;
mod handle_press_side;
mod handle_pull;
mod handle_pull_side;

/// A scripted policy: observation in, action out.
pub type Policy = fn(&[f64; OBS_DIM]) -> [f32; ACTION_DIM];

static POLICIES: &[(&str, Policy)] = &[
    ("reach-v3", reach::action),
    ("push-v3", push::action),
    ("pick-place-v3", pick_place::action),
    ("door-open-v3", door_open::action),
    ("drawer-open-v3", drawer_open::action),
    ("drawer-close-v3", drawer_close::action),
    ("button-press-topdown-v3", button_press_topdown::action),
    ("peg-insert-side-v3", peg_insert_side::action),
    ("window-open-v3", window_open::action),
    ("window-close-v3", window_close::action),
    ("door-close-v3", door_close::action),
    ("door-lock-v3", door_lock::action),
    ("door-unlock-v3", door_unlock::action),
    ("button-press-v3", button_press::action),
    ("coffee-button-v3", coffee_button::action),
    ("dial-turn-v3", dial_turn::action),
    ("faucet-open-v3", faucet_open::action),
    ("faucet-close-v3", faucet_close::action),
    ("handle-press-v3", handle_press::action),
    ("plate-slide-v3", plate_slide::action),
    ("sweep-into-v3", sweep_into::action),
    ("shelf-place-v3", shelf_place::action),
    ("lever-pull-v3", lever_pull::action),
    // MT50 tasks, part A.
    ("assembly-v3", assembly::action),
    ("basketball-v3", basketball::action),
    ("bin-picking-v3", bin_picking::action),
    ("box-close-v3", box_close::action),
    (
        "button-press-topdown-wall-v3",
        button_press_topdown_wall::action,
    ),
    ("button-press-wall-v3", button_press_wall::action),
    ("coffee-pull-v3", coffee_pull::action),
    ("coffee-push-v3", coffee_push::action),
    ("disassemble-v3", disassemble::action),
    ("hammer-v3", hammer::action),
    ("hand-insert-v3", hand_insert::action),
    ("handle-press-side-v3", handle_press_side::action),
    ("handle-pull-side-v3", handle_pull_side::action),
    ("handle-pull-v3", handle_pull::action),
    ("peg-unplug-side-v3", peg_unplug_side::action),
    ("pick-out-of-hole-v3", pick_out_of_hole::action),
    ("pick-place-wall-v3", pick_place_wall::action),
    ("plate-slide-back-v3", plate_slide_back::action),
    ("plate-slide-back-side-v3", plate_slide_back_side::action),
    ("plate-slide-side-v3", plate_slide_side::action),
    ("push-back-v3", push_back::action),
    ("push-wall-v3", push_wall::action),
    ("reach-wall-v3", reach_wall::action),
    ("soccer-v3", soccer::action),
    ("stick-pull-v3", stick_pull::action),
    ("stick-push-v3", stick_push::action),
    ("sweep-v3", sweep::action),
];

/// Tasks that have a scripted policy (whether or not the task itself is registered).
pub fn policy_names() -> Vec<&'static str> {
    POLICIES.iter().map(|(name, _)| *name).collect()
}

/// The scripted policy of a task (`"reach-v3"`; `"reach"` is accepted too).
pub fn policy(task: &str) -> Result<Policy> {
    let full = if task.ends_with("-v3") {
        task.to_string()
    } else {
        format!("{task}-v3")
    };
    POLICIES
        .iter()
        .find(|(name, _)| *name == full)
        .map(|(_, p)| *p)
        .ok_or_else(|| SimError::NoPolicy {
            name: task.to_string(),
            available: policy_names().join(", "),
        })
}

/// The scripted action of `task` for one observation.
pub fn scripted_action(task: &str, obs: &[f64; OBS_DIM]) -> Result<[f32; ACTION_DIM]> {
    Ok(policy(task)?(obs))
}

// Helpers shared by the policies, mirroring `metaworld.policies.policy`.

type V3 = [f64; 3];

/// Hand position, obs[0..3].
fn hand(obs: &[f64; OBS_DIM]) -> V3 {
    [obs[0], obs[1], obs[2]]
}

/// First object's position, obs[4..7].
fn object(obs: &[f64; OBS_DIM]) -> V3 {
    [obs[4], obs[5], obs[6]]
}

/// Goal position, obs[36..39].
fn goal(obs: &[f64; OBS_DIM]) -> V3 {
    [obs[36], obs[37], obs[38]]
}

fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Distance in the XY plane.
fn xy_dist(a: V3, b: V3) -> f64 {
    let (dx, dy) = (a[0] - b[0], a[1] - b[1]);
    (dx * dx + dy * dy).sqrt()
}

/// Distance in 3D.
fn dist(a: V3, b: V3) -> f64 {
    let (dx, dy, dz) = (a[0] - b[0], a[1] - b[1], a[2] - b[2]);
    (dx * dx + dy * dy + dz * dz).sqrt()
}

/// The gripper effort of most grasping policies' `_grab_effort`: `far` while the hand is more
/// than `xy` from `obj` in the plane or more than `z` from it in height, else `near`.
fn grab_near(hand: V3, obj: V3, xy: f64, z: f64, far: f64, near: f64) -> f64 {
    if xy_dist(hand, obj) > xy || (hand[2] - obj[2]).abs() > z {
        far
    } else {
        near
    }
}

/// The shape of most grasping policies' `get_action`: the hand moves with gain `p` to
/// `desired_pos(hand, object, goal)`, the gripper at `grab_effort(hand, object)`.
fn object_to_goal(
    obs: &[f64; OBS_DIM],
    p: f64,
    desired_pos: fn(V3, V3, V3) -> V3,
    grab_effort: fn(V3, V3) -> f64,
) -> [f32; ACTION_DIM] {
    let (hand, obj) = (hand(obs), object(obs));
    act(
        hand,
        desired_pos(hand, obj, goal(obs)),
        p,
        grab_effort(hand, obj),
    )
}

/// The three phases of the faucet and window policies: above `obj + offset` (by `above`)
/// until the hand is within `xy` of it in the plane, down to it until within `z` in height,
/// then on to `obj + offset + push`.
fn above_down_push(hand: V3, obj: V3, offset: V3, (xy, above, z): (f64, f64, f64), push: V3) -> V3 {
    let obj = add(obj, offset);
    if xy_dist(hand, obj) > xy {
        add(obj, [0.0, 0.0, above])
    } else if (hand[2] - obj[2]).abs() > z {
        obj
    } else {
        add(obj, push)
    }
}

/// `move(from, to, p)` (unclipped, as in Python) plus the gripper effort, as float32.
fn act(from: V3, to: V3, p: f64, grab: f64) -> [f32; ACTION_DIM] {
    [
        ((to[0] - from[0]) * p) as f32,
        ((to[1] - from[1]) * p) as f32,
        ((to[2] - from[2]) * p) as f32,
        grab as f32,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lookup_accepts_short_names_and_rejects_unknown_tasks() {
        assert!(policy("reach").is_ok());
        assert!(policy("reach-v3").is_ok());
        let err = policy("juggle-v3").unwrap_err().to_string();
        assert!(
            err.contains("juggle-v3") && err.contains("reach-v3"),
            "{err}"
        );
    }

    #[test]
    fn reach_moves_toward_the_goal() {
        let mut obs = [0.0; OBS_DIM];
        obs[..3].copy_from_slice(&[0.0, 0.6, 0.2]);
        obs[36..].copy_from_slice(&[0.1, 0.8, 0.2]);
        let a = scripted_action("reach-v3", &obs).unwrap();
        assert_eq!(a, [0.5, 1.0, 0.0, 0.0]);
    }
}
