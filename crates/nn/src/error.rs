//! Errors of this crate: shape and dtype mismatches when loading tensors, malformed files.

use thiserror::Error;

/// Everything that can go wrong when (de)serialising networks and optimiser state.
#[derive(Debug, Error)]
pub enum NnError {
    /// A tensor that the network needs is not in the file.
    #[error("tensor `{name}` is missing")]
    MissingTensor {
        /// The name the caller asked for.
        name: String,
    },
    /// A tensor has a different shape than the network expects.
    #[error("tensor `{name}` has shape {found:?}, expected {expected:?}")]
    ShapeMismatch {
        /// The tensor's name.
        name: String,
        /// The shape the caller asked for.
        expected: Vec<usize>,
        /// The tensor's actual shape.
        found: Vec<usize>,
    },
    /// A tensor has a different element type than the network expects.
    #[error("tensor `{name}` has dtype {found}, expected {expected}")]
    DtypeMismatch {
        /// The tensor's name.
        name: String,
        /// The dtype the caller asked for (`F32`, `F64` or `I64`).
        expected: String,
        /// The tensor's actual dtype.
        found: String,
    },
    /// The bytes are not a valid safetensors file.
    #[error("invalid safetensors data: {0}")]
    Format(String),
    /// The file's content does not match the checksum stored in it (a damaged file).
    #[error("the content does not match its checksum (stored {stored}, computed {computed}): the file is damaged")]
    Checksum {
        /// The checksum stored in the file (`crc32:` and eight hex digits).
        stored: String,
        /// The checksum of the content as read.
        computed: String,
    },
    /// A value could not be represented (for example a non-finite weight was asked to load).
    #[error("invalid value: {0}")]
    InvalidValue(String),
    /// Reading or writing a file failed.
    #[error("i/o error on `{path}`: {source}")]
    Io {
        /// The file that was being read or written.
        path: String,
        /// The underlying I/O error.
        source: std::io::Error,
    },
}
