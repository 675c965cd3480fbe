use std::path::PathBuf;

/// Everything that can go wrong below the task layer.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(
        "MuJoCo library not found at {path}: run ./deploy/setup.sh (or set TERL_MUJOCO_LIB to a libmujoco.so 3.3.7)"
    )]
    LibraryMissing { path: PathBuf },
    #[error("cannot load MuJoCo library {path}: {reason}")]
    LibraryLoad { path: PathBuf, reason: String },
    #[error("MuJoCo version mismatch: library is {found}, terl is built for {expected}")]
    Version { found: i32, expected: i32 },
    #[error(
        "Meta-World assets not found at {path}: run ./deploy/setup.sh (or set TERL_METAWORLD_ASSETS)"
    )]
    AssetsMissing { path: PathBuf },
    #[error("MuJoCo could not load {path}: {message}")]
    ModelLoad { path: PathBuf, message: String },
    #[error(
        "{task}: MuJoCo ran out of its mjData arena ({arena_bytes} bytes, peak use \
         {peak_bytes}) and dropped contacts or constraints (mjWARN_CONTACTFULL/CNSTRFULL); \
         the episode is void: raise TERL_MUJOCO_ARENA_BYTES"
    )]
    ArenaFull {
        task: &'static str,
        arena_bytes: usize,
        peak_bytes: usize,
    },
    #[error("MuJoCo could not allocate {what}")]
    Alloc { what: &'static str },
    #[error("no {kind} named {name:?} in the model")]
    UnknownName { kind: &'static str, name: String },
    #[error("unknown task {name:?}; valid tasks: {valid}")]
    UnknownTask { name: String, valid: String },
    #[error("unknown task set {name:?}; valid sets: {valid}")]
    UnknownTaskSet { name: String, valid: String },
    #[error("no scripted policy for task {name:?}; policies exist for: {available}")]
    NoPolicy { name: String, available: String },
    #[error("{what} has length {got}, expected {expected}")]
    Length {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{what} contains a non-finite value at index {index}")]
    NonFinite { what: &'static str, index: usize },
    #[error("{what} is outside its valid range: {detail}")]
    OutOfRange { what: &'static str, detail: String },
    #[error("the episode is over (truncated at step {0}); reset before stepping")]
    EpisodeOver(u32),
    #[error("trace error: {0}")]
    Trace(String),
    #[error("io error on {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

pub type Result<T, E = SimError> = std::result::Result<T, E>;
