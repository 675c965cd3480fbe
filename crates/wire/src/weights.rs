//! Weight versions as the rest of terl sees them, and their wire form.
//!
//! A [`Weights`] value is always valid: every tensor's shape matches its value count, every value
//! is finite, names are unique and non-empty. Wire messages become `Weights` only through
//! [`TryFrom<pb::WeightsUpdate>`], which checks all of that plus the kind and the CRC-32 and
//! answers [`Status::invalid_argument`] naming the first problem. The reverse direction encodes
//! little-endian `f32` bytes and computes the checksum.

use std::collections::HashSet;
use std::fmt;

use prost::bytes::Bytes;
use tonic::Status;

use crate::pb;

/// What a set of weights is for (mirrors `terl.v1.WeightsKind` without its UNSPECIFIED value).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum WeightsKind {
    /// The MTSAC policy the actors act with.
    Policy,
    /// The TEP planner (reachability net F and action net AN).
    Planner,
    /// The twin Q critics (for the selector's PTR scoring).
    Critic,
}

impl WeightsKind {
    /// All kinds, in wire order.
    pub const ALL: [WeightsKind; 3] = [Self::Policy, Self::Planner, Self::Critic];

    /// Dense index 0..3, for per-kind arrays.
    pub fn index(self) -> usize {
        match self {
            Self::Policy => 0,
            Self::Planner => 1,
            Self::Critic => 2,
        }
    }

    /// Lower-case name used in logs and JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Policy => "policy",
            Self::Planner => "planner",
            Self::Critic => "critic",
        }
    }
}

impl fmt::Display for WeightsKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl From<WeightsKind> for pb::WeightsKind {
    fn from(kind: WeightsKind) -> Self {
        match kind {
            WeightsKind::Policy => pb::WeightsKind::Policy,
            WeightsKind::Planner => pb::WeightsKind::Planner,
            WeightsKind::Critic => pb::WeightsKind::Critic,
        }
    }
}

impl TryFrom<i32> for WeightsKind {
    type Error = Status;

    /// Decodes the raw enum value of a wire message; UNSPECIFIED and unknown values are invalid.
    fn try_from(raw: i32) -> Result<Self, Status> {
        match pb::WeightsKind::try_from(raw) {
            Ok(pb::WeightsKind::Policy) => Ok(Self::Policy),
            Ok(pb::WeightsKind::Planner) => Ok(Self::Planner),
            Ok(pb::WeightsKind::Critic) => Ok(Self::Critic),
            Ok(pb::WeightsKind::Unspecified) => Err(Status::invalid_argument(
                "weights kind is WEIGHTS_KIND_UNSPECIFIED; expected POLICY, PLANNER or CRITIC",
            )),
            Err(_) => Err(Status::invalid_argument(format!(
                "unknown weights kind {raw}; expected 1 (POLICY), 2 (PLANNER) or 3 (CRITIC)"
            ))),
        }
    }
}

/// Why a tensor or weight set could not be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum WeightsError {
    /// A tensor has an empty name.
    #[error("tensor name is empty")]
    EmptyName,
    /// A tensor's shape does not multiply out to its number of values.
    #[error("tensor '{name}': shape {shape:?} has {expected} elements, got {actual} values")]
    ShapeMismatch {
        /// The tensor's name.
        name: String,
        /// Its declared shape.
        shape: Vec<usize>,
        /// Elements the shape implies (`usize::MAX` if the product overflows).
        expected: usize,
        /// Values given.
        actual: usize,
    },
    /// A tensor holds NaN or an infinity.
    #[error("tensor '{name}': value {index} is not finite ({value})")]
    NotFinite {
        /// The tensor's name.
        name: String,
        /// Row-major index of the first non-finite value.
        index: usize,
        /// That value as text (`NaN`, `inf`, `-inf`).
        value: String,
    },
    /// Two tensors of one weight set share a name.
    #[error("tensor name '{0}' appears twice")]
    DuplicateName(String),
    /// A weight set without tensors.
    #[error("weights have no tensors")]
    Empty,
    /// A weight set of version 0, which means "no weights yet".
    #[error("weights version must be at least 1 (0 means 'no weights yet')")]
    ZeroVersion,
}

impl From<WeightsError> for Status {
    fn from(err: WeightsError) -> Self {
        Status::invalid_argument(err.to_string())
    }
}

/// One named, row-major `f32` tensor whose shape matches its values and whose values are finite.
#[derive(Clone, PartialEq)]
pub struct Tensor {
    name: String,
    shape: Vec<usize>,
    values: Vec<f32>,
}

impl fmt::Debug for Tensor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Tensor")
            .field("name", &self.name)
            .field("shape", &self.shape)
            .field("values", &format_args!("[{} f32]", self.values.len()))
            .finish()
    }
}

impl Tensor {
    /// Checks that `shape` has `values.len()` elements (an empty shape is a scalar) and that every
    /// value is finite.
    pub fn new(
        name: impl Into<String>,
        shape: Vec<usize>,
        values: Vec<f32>,
    ) -> Result<Self, WeightsError> {
        let name = name.into();
        if name.is_empty() {
            return Err(WeightsError::EmptyName);
        }
        let expected = element_count(&shape);
        if expected != Some(values.len()) {
            return Err(WeightsError::ShapeMismatch {
                name,
                shape,
                expected: expected.unwrap_or(usize::MAX),
                actual: values.len(),
            });
        }
        if let Some(index) = first_non_finite(&values) {
            let value = values[index].to_string();
            return Err(WeightsError::NotFinite { name, index, value });
        }
        Ok(Self {
            name,
            shape,
            values,
        })
    }

    /// The tensor's name, e.g. `policy.0.weight` (see `terl_rl::names`; never empty).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its shape, outermost dimension first (empty for a scalar).
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// Its values, row-major, all finite; as many as the shape's product.
    pub fn values(&self) -> &[f32] {
        &self.values
    }

    /// Takes the parts apart (name, shape, values).
    pub fn into_parts(self) -> (String, Vec<usize>, Vec<f32>) {
        (self.name, self.shape, self.values)
    }
}

/// One complete version of one kind of weights.
#[derive(Clone, PartialEq)]
pub struct Weights {
    kind: WeightsKind,
    version: u64,
    learner_update: u64,
    tensors: Vec<Tensor>,
}

impl fmt::Debug for Weights {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Weights")
            .field("kind", &self.kind)
            .field("version", &self.version)
            .field("learner_update", &self.learner_update)
            .field("tensors", &self.tensors)
            .finish()
    }
}

impl Weights {
    /// `version` must be ≥ 1 and tensors non-empty with unique names.
    pub fn new(
        kind: WeightsKind,
        version: u64,
        learner_update: u64,
        tensors: Vec<Tensor>,
    ) -> Result<Self, WeightsError> {
        if version == 0 {
            return Err(WeightsError::ZeroVersion);
        }
        if tensors.is_empty() {
            return Err(WeightsError::Empty);
        }
        let mut names = HashSet::with_capacity(tensors.len());
        for tensor in &tensors {
            if !names.insert(tensor.name.as_str()) {
                return Err(WeightsError::DuplicateName(tensor.name.clone()));
            }
        }
        Ok(Self {
            kind,
            version,
            learner_update,
            tensors,
        })
    }

    /// Which network set these are (policy, planner or critics).
    pub fn kind(&self) -> WeightsKind {
        self.kind
    }

    /// The version, ≥ 1 and strictly increasing per kind; actors stamp it on every transition
    /// they produce.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Learner update count at which these weights were taken.
    pub fn learner_update(&self) -> u64 {
        self.learner_update
    }

    /// The tensors, in message order, names unique.
    pub fn tensors(&self) -> &[Tensor] {
        &self.tensors
    }

    /// The tensor called `name`, if any.
    pub fn tensor(&self, name: &str) -> Option<&Tensor> {
        self.tensors.iter().find(|t| t.name == name)
    }

    /// Takes the tensors out, in message order.
    pub fn into_tensors(self) -> Vec<Tensor> {
        self.tensors
    }

    /// All values, tensor after tensor: the flat parameter vector the networks load
    /// (`Policy::set_params`, `ValueEstimator::set_critics`).
    pub fn into_flat(self) -> Vec<f32> {
        self.tensors
            .into_iter()
            .flat_map(|t| t.into_parts().2)
            .collect()
    }

    /// Total number of `f32` parameters.
    pub fn parameter_count(&self) -> usize {
        self.tensors.iter().map(|t| t.values.len()).sum()
    }
}

/// Product of the dimensions, `None` on overflow.
fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

/// CRC-32 (IEEE) over the data of all tensors in order: the `crc32` field of `WeightsUpdate`.
pub fn weights_crc32(tensors: &[pb::Tensor]) -> u32 {
    let mut hasher = crc32fast::Hasher::new();
    for tensor in tensors {
        hasher.update(&tensor.data);
    }
    hasher.finalize()
}

/// Little-endian bytes (length a multiple of 4, checked by the caller) to `f32`s. Written as a
/// plain indexed loop so it compiles to a vectorised copy on little-endian targets.
fn decode_f32_le(data: &[u8]) -> Vec<f32> {
    let mut values = vec![0f32; data.len() / 4];
    for (value, bytes) in values.iter_mut().zip(data.chunks_exact(4)) {
        *value = f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
    }
    values
}

/// Index of the first NaN or infinity. The branch-free scan runs first (vectorised); the
/// position is searched only when something was found.
fn first_non_finite(values: &[f32]) -> Option<usize> {
    let all_finite = values.iter().fold(true, |ok, v| ok & v.is_finite());
    if all_finite {
        None
    } else {
        values.iter().position(|v| !v.is_finite())
    }
}

fn encode_f32_le(values: &[f32]) -> Bytes {
    let mut data = vec![0u8; values.len() * 4];
    for (bytes, v) in data.chunks_exact_mut(4).zip(values) {
        bytes.copy_from_slice(&v.to_le_bytes());
    }
    Bytes::from(data)
}

impl From<&Weights> for pb::WeightsUpdate {
    fn from(weights: &Weights) -> Self {
        let tensors: Vec<pb::Tensor> = weights
            .tensors
            .iter()
            .map(|t| pb::Tensor {
                name: t.name.clone(),
                shape: t.shape.iter().map(|&d| d as u64).collect(),
                data: encode_f32_le(&t.values),
            })
            .collect();
        let crc32 = weights_crc32(&tensors);
        pb::WeightsUpdate {
            kind: pb::WeightsKind::from(weights.kind) as i32,
            version: weights.version,
            learner_update: weights.learner_update,
            tensors,
            crc32,
        }
    }
}

impl From<Weights> for pb::WeightsUpdate {
    fn from(weights: Weights) -> Self {
        (&weights).into()
    }
}

impl TryFrom<pb::WeightsUpdate> for Weights {
    type Error = Status;

    /// Validates kind, version, every tensor's shape against its byte length, finiteness and the
    /// CRC-32, in that order, and reports the first failure as `invalid_argument`.
    fn try_from(msg: pb::WeightsUpdate) -> Result<Self, Status> {
        let kind = WeightsKind::try_from(msg.kind)?;
        let context = |what: String| {
            Status::invalid_argument(format!("{kind} weights version {}: {what}", msg.version))
        };
        if msg.version == 0 {
            return Err(context(WeightsError::ZeroVersion.to_string()));
        }
        let actual_crc = weights_crc32(&msg.tensors);
        let mut tensors = Vec::with_capacity(msg.tensors.len());
        for (index, t) in msg.tensors.iter().enumerate() {
            let shape: Vec<usize> = t
                .shape
                .iter()
                .map(|&d| usize::try_from(d))
                .collect::<Result<_, _>>()
                .map_err(|_| {
                    context(format!(
                        "tensor '{}' (#{index}): dimension too large in {:?}",
                        t.name, t.shape
                    ))
                })?;
            let expected_bytes = element_count(&shape).and_then(|n| n.checked_mul(4));
            if expected_bytes != Some(t.data.len()) {
                return Err(context(format!(
                    "tensor '{}' (#{index}): shape {:?} needs {} bytes of little-endian f32, got {}",
                    t.name,
                    t.shape,
                    expected_bytes.map_or("more than usize::MAX".into(), |n| n.to_string()),
                    t.data.len()
                )));
            }
            let values = decode_f32_le(&t.data);
            if let Some(i) = first_non_finite(&values) {
                return Err(context(format!(
                    "tensor '{}' (#{index}): value {i} is not finite ({})",
                    t.name, values[i]
                )));
            }
            if t.name.is_empty() {
                return Err(context(format!(
                    "tensor #{index}: {}",
                    WeightsError::EmptyName
                )));
            }
            let tensor = Tensor {
                name: t.name.clone(),
                shape,
                values,
            };
            tensors.push(tensor);
        }
        // Checked after the shapes so a truncated tensor is reported as such, and before
        // accepting anything so corrupted-but-finite data never reaches a network.
        if actual_crc != msg.crc32 {
            return Err(context(format!(
                "CRC-32 mismatch: message says {:#010x}, data hashes to {actual_crc:#010x}",
                msg.crc32
            )));
        }
        Weights::new(kind, msg.version, msg.learner_update, tensors)
            .map_err(|e| context(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tonic::Code;

    fn sample() -> Weights {
        Weights::new(
            WeightsKind::Policy,
            3,
            300,
            vec![
                Tensor::new(
                    "l0.weight",
                    vec![2, 3],
                    vec![1.0, -2.0, 3.5, 0.0, 1e-3, 7.0],
                )
                .unwrap(),
                Tensor::new("l0.bias", vec![2], vec![0.25, -0.5]).unwrap(),
                Tensor::new("log_alpha", vec![], vec![-1.0]).unwrap(),
            ],
        )
        .unwrap()
    }

    #[test]
    fn round_trip_preserves_everything() {
        let w = sample();
        let msg = pb::WeightsUpdate::from(&w);
        assert_eq!(msg.tensors[0].data.len(), 24);
        assert_eq!(&msg.tensors[1].data[..4], &0.25f32.to_le_bytes());
        assert_eq!(Weights::try_from(msg).unwrap(), w);
    }

    #[test]
    fn crc_is_zlib_crc32_of_concatenated_data() {
        let msg = pb::WeightsUpdate::from(&sample());
        let mut all = Vec::new();
        for t in &msg.tensors {
            all.extend_from_slice(&t.data);
        }
        assert_eq!(msg.crc32, crc32fast::hash(&all));
        // Known value: zlib.crc32(b"123456789") == 0xcbf43926.
        assert_eq!(crc32fast::hash(b"123456789"), 0xcbf4_3926);
    }

    fn rejected(msg: pb::WeightsUpdate) -> String {
        let status = Weights::try_from(msg).unwrap_err();
        assert_eq!(status.code(), Code::InvalidArgument);
        status.message().to_owned()
    }

    #[test]
    fn rejects_bad_messages_with_precise_messages() {
        let good = pb::WeightsUpdate::from(&sample());

        let mut m = good.clone();
        m.crc32 ^= 1;
        assert!(rejected(m).contains("CRC-32 mismatch"));

        let mut m = good.clone();
        m.tensors[0].shape = vec![3, 3];
        let text = rejected(m);
        assert!(
            text.contains("'l0.weight'") && text.contains("needs 36 bytes"),
            "{text}"
        );

        let mut m = good.clone();
        m.tensors[1].data = Bytes::from([f32::NAN.to_le_bytes(), 1f32.to_le_bytes()].concat());
        m.crc32 = weights_crc32(&m.tensors);
        let text = rejected(m);
        assert!(
            text.contains("not finite") && text.contains("l0.bias"),
            "{text}"
        );

        let mut m = good.clone();
        m.kind = 0;
        assert!(rejected(m).contains("UNSPECIFIED"));
        let mut m = good.clone();
        m.kind = 9;
        assert!(rejected(m).contains("unknown weights kind 9"));

        let mut m = good.clone();
        m.version = 0;
        assert!(rejected(m).contains("version must be at least 1"));

        let mut m = good.clone();
        m.tensors[2].name = "l0.bias".into();
        assert!(rejected(m).contains("appears twice"));

        let mut m = good;
        m.tensors[0].shape = vec![u64::MAX, 2];
        assert!(rejected(m).contains("more than usize::MAX"));
    }

    #[test]
    fn constructor_rejects_inconsistent_tensors() {
        assert!(matches!(
            Tensor::new("a", vec![2, 2], vec![0.0; 3]),
            Err(WeightsError::ShapeMismatch {
                expected: 4,
                actual: 3,
                ..
            })
        ));
        assert!(matches!(
            Tensor::new("a", vec![1], vec![f32::INFINITY]),
            Err(WeightsError::NotFinite { index: 0, .. })
        ));
        assert_eq!(
            Tensor::new("", vec![], vec![0.0]),
            Err(WeightsError::EmptyName)
        );
        assert_eq!(
            Weights::new(WeightsKind::Critic, 1, 0, vec![]),
            Err(WeightsError::Empty)
        );
    }
}
