//! The bounds a run file's network, batch and thread settings are checked against (SAC, CARE
//! and the planner alike), in one place so that the configs that check them need not import
//! each other.

/// Widest hidden layer a config accepts (a 16384² layer is 1 GiB of f32 weights).
pub const MAX_WIDTH: usize = 16_384;

/// Most weights and biases a network (SAC's, CARE's encoder) or the planner's F and AN together
/// may have (about 200 MB each for weights, targets and the two Adam moments).
pub const MAX_PARAMETERS: usize = 50_000_000;

/// Largest minibatch a config accepts.
pub const MAX_BATCH: usize = 65_536;

/// Most hidden layers of a policy or critic network.
pub const MAX_LAYERS: usize = 16;

/// Most update threads [`crate::SacConfig::threads`] accepts.
pub const MAX_THREADS: usize = 256;
