use std::path::PathBuf;

/// Everything that can go wrong below the task layer.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// No file at the MuJoCo shared library's path ([`crate::mujoco::library_path`]). Reaches
    /// callers as the `reason` of [`SimError::LibraryLoad`], since the load's outcome is cached
    /// process-wide as text.
    #[error(
        "MuJoCo library not found at {path}: run ./deploy/setup.sh (or set TERL_MUJOCO_LIB to a libmujoco.so 3.3.7)"
    )]
    LibraryMissing {
        /// The path looked at.
        path: PathBuf,
    },
    /// The MuJoCo library could not be used: what every MuJoCo call answers when the
    /// process-wide load failed (missing file, `dlopen` or symbol lookup failure, version
    /// mismatch).
    #[error("cannot load MuJoCo library {path}: {reason}")]
    LibraryLoad {
        /// The library's path.
        path: PathBuf,
        /// Why: the loader's message or the text of the original [`SimError`].
        reason: String,
    },
    /// The loaded library's `mj_version()` is not the one the bindings were generated for.
    /// Reaches callers as the `reason` of [`SimError::LibraryLoad`].
    #[error("MuJoCo version mismatch: library is {found}, terl is built for {expected}")]
    Version {
        /// `mj_version()` of the loaded library (e.g. 337 for 3.3.7).
        found: i32,
        /// [`crate::mujoco::MUJOCO_VERSION`].
        expected: i32,
    },
    /// The Meta-World XML/STL assets folder ([`crate::metaworld::assets_dir`]) lacks the
    /// scene file.
    #[error(
        "Meta-World assets not found at {path}: run ./deploy/setup.sh (or set TERL_METAWORLD_ASSETS)"
    )]
    AssetsMissing {
        /// The assets folder looked in.
        path: PathBuf,
    },
    /// MuJoCo's parser or compiler rejected an MJCF file.
    #[error("MuJoCo could not load {path}: {message}")]
    ModelLoad {
        /// The MJCF file.
        path: PathBuf,
        /// MuJoCo's error message.
        message: String,
    },
    /// The `mjData` arena overflowed during a reset or step (`mjWARN_CONTACTFULL` or
    /// `mjWARN_CNSTRFULL`); the env must be reset.
    #[error(
        "{task}: MuJoCo ran out of its mjData arena ({arena_bytes} bytes, peak use \
         {peak_bytes}) and dropped contacts or constraints (mjWARN_CONTACTFULL/CNSTRFULL); \
         the episode is void: raise TERL_MUJOCO_ARENA_BYTES"
    )]
    ArenaFull {
        /// Meta-World v3 name of the env's task.
        task: &'static str,
        /// Size of the simulation's arena (`mjData.narena`), bytes.
        arena_bytes: usize,
        /// Peak arena use (`mjData.maxuse_arena`), bytes.
        peak_bytes: usize,
    },
    /// `mj_makeData` (or another MuJoCo allocation) returned null.
    #[error("MuJoCo could not allocate {what}")]
    Alloc {
        /// What was being allocated, e.g. `"mjData"`.
        what: &'static str,
    },
    /// `mj_name2id` found no object of this kind and name.
    #[error("no {kind} named {name:?} in the model")]
    UnknownName {
        /// Object kind: `"body"`, `"joint"`, `"geom"` or `"site"`.
        kind: &'static str,
        /// The name looked up.
        name: String,
    },
    /// No task of the registry has this Meta-World v3 name.
    #[error("unknown task {name:?}; valid tasks: {valid}")]
    UnknownTask {
        /// The name given.
        name: String,
        /// The registry's task names, comma separated.
        valid: String,
    },
    /// No benchmark task set ([`crate::metaworld::task_set_names`]) has this name.
    #[error("unknown task set {name:?}; valid sets: {valid}")]
    UnknownTaskSet {
        /// The name given.
        name: String,
        /// The known set names, comma separated.
        valid: String,
    },
    /// The task has no scripted policy in [`crate::metaworld::policies`].
    #[error("no scripted policy for task {name:?}; policies exist for: {available}")]
    NoPolicy {
        /// The task name given.
        name: String,
        /// The tasks that have a policy, comma separated.
        available: String,
    },
    /// An input slice (action, `rand_vec`, a batch of actions) has the wrong length.
    #[error("{what} has length {got}, expected {expected}")]
    Length {
        /// The input, e.g. `"action"`.
        what: &'static str,
        /// Its length.
        got: usize,
        /// The length required.
        expected: usize,
    },
    /// An input contains NaN or an infinity.
    #[error("{what} contains a non-finite value at index {index}")]
    NonFinite {
        /// The input, e.g. `"action"`.
        what: &'static str,
        /// Index of the first non-finite entry.
        index: usize,
    },
    /// An input is outside its valid range (a `rand_vec` entry outside the task's bounds or
    /// against its placement rule, a goal variation index not in `0..50`).
    #[error("{what} is outside its valid range: {detail}")]
    OutOfRange {
        /// The input, e.g. `"rand_vec"`.
        what: &'static str,
        /// Which entry and which bound.
        detail: String,
    },
    /// [`crate::Env::step`] before the first reset or after the episode ended (time limit,
    /// instability or arena overflow); the field is the episode's step count.
    #[error("the episode is over (truncated at step {0}); reset before stepping")]
    EpisodeOver(u32),
    /// A trace file ([`crate::trace`]) is malformed: bad JSON, missing fields, wrong shapes.
    #[error("trace error: {0}")]
    Trace(String),
    /// Offscreen rendering is not possible or was misused ([`crate::render`]): no EGL or Mesa
    /// OpenGL (the message names the Debian packages), a frame size out of range, a model
    /// without its rendering arrays, a renderer used with another model.
    #[error("cannot render: {reason}")]
    Render {
        /// What failed and, for a missing library, what to install.
        reason: String,
    },
    /// Reading or writing a file failed.
    #[error("io error on {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
}

/// `Result` with [`SimError`] as the default error type.
pub type Result<T, E = SimError> = std::result::Result<T, E>;
