//! Errors of the learning core.

use thiserror::Error;

/// Why an update, a load or a training run stopped.
#[derive(Debug, Error)]
pub enum SacError {
    /// The batch holds NaN or infinity; it was rejected before touching any weight.
    #[error("batch rejected: non-finite value in `{field}` at row {row}")]
    NonFiniteBatch {
        /// The [`crate::Batch`] field, e.g. `"obs"`.
        field: &'static str,
        /// The first row holding the value.
        row: usize,
    },
    /// A loss became NaN or infinite; the update stopped and no weight changed.
    #[error("update stopped: {loss} loss is not finite ({value}); weights unchanged")]
    NonFiniteLoss {
        /// Which loss: `"qf1"`, `"qf2"`, `"actor"`, `"alpha"` (SAC) or `"tep f"`, `"tep an"`.
        loss: &'static str,
        /// Its value.
        value: f64,
    },
    /// A gradient became NaN or infinite; the update stopped and no weight changed.
    #[error("update stopped: non-finite gradient in {network}; weights unchanged")]
    NonFiniteGradient {
        /// The network whose gradient it was.
        network: &'static str,
    },
    /// A batch or observation does not fit the configured sizes.
    #[error("shape error: {0}")]
    Shape(String),
    /// The configuration is inconsistent.
    #[error("invalid config: {0}")]
    Config(String),
    /// Loading or saving weights failed.
    #[error(transparent)]
    Tensors(#[from] terl_nn::NnError),
    /// The environment failed.
    #[error("environment error: {0}")]
    Env(Box<dyn std::error::Error + Send + Sync>),
}
