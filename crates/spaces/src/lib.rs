//! The fixed sizes of the Meta-World v3 benchmark, defined once.
//!
//! The simulator (`terl-sim`) steps environments of these sizes, and the message formats
//! (`terl-transport`'s shared-memory messages, `terl-wire`'s datasets) carry them. Both depend on
//! this crate rather than on each other, so the message crates build without MuJoCo's FFI.
//!
//! Source: Meta-World 3.1.1, `metaworld/envs/sawyer_xyz_env.py` (`SawyerXYZEnv`:
//! `_HAND_SPACE`, `action_space`, `max_path_length`, the 39-wide `observation_space`) and
//! `metaworld/__init__.py` (`_N_GOALS = 50`).

#![warn(missing_docs)]
#![no_std]

/// Observation length (fully observable Meta-World: hand xyz, gripper opening, two objects'
/// position and quaternion, the previous frame of the same 18 values, goal xyz).
pub const OBS_DIM: usize = 39;
/// Action length (hand delta xyz, gripper), each in `[-1, 1]`.
pub const ACTION_DIM: usize = 4;
/// Episode length in env steps (`max_path_length`).
pub const MAX_PATH_LENGTH: u32 = 500;
/// Goal variations per task, as in the Meta-World benchmarks (`_N_GOALS`).
pub const NUM_VARIATIONS: usize = 50;
