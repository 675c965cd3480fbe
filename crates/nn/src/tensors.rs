//! Named tensors and their safetensors encoding (8-byte little-endian header length, JSON header,
//! raw little-endian data), readable by PyTorch's `safetensors.torch.load_file` and other tools.
//!
//! Loading is strict: a tensor the caller asks for must exist with exactly the expected shape and
//! dtype, otherwise a [`NnError`] names the tensor and both shapes or dtypes.

use crate::error::NnError;
use crate::scalar::Float;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Element types used by this project's tensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    F32,
    F64,
    I64,
}

impl Dtype {
    fn to_st(self) -> safetensors::Dtype {
        match self {
            Dtype::F32 => safetensors::Dtype::F32,
            Dtype::F64 => safetensors::Dtype::F64,
            Dtype::I64 => safetensors::Dtype::I64,
        }
    }

    fn from_st(dtype: safetensors::Dtype) -> Option<Self> {
        match dtype {
            safetensors::Dtype::F32 => Some(Dtype::F32),
            safetensors::Dtype::F64 => Some(Dtype::F64),
            safetensors::Dtype::I64 => Some(Dtype::I64),
            _ => None,
        }
    }

    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::F32 => 4,
            Dtype::F64 | Dtype::I64 => 8,
        }
    }
}

impl std::fmt::Display for Dtype {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let s = match self {
            Dtype::F32 => "F32",
            Dtype::F64 => "F64",
            Dtype::I64 => "I64",
        };
        f.write_str(s)
    }
}

/// One named tensor with its data as little-endian bytes (row-major, C order).
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub name: String,
    pub shape: Vec<usize>,
    pub dtype: Dtype,
    pub data: Vec<u8>,
}

impl Tensor {
    /// A float tensor from values in row-major order.
    pub fn from_values<T: Float>(name: impl Into<String>, shape: Vec<usize>, values: &[T]) -> Self {
        assert_eq!(
            shape.iter().product::<usize>(),
            values.len(),
            "tensor shape/value count mismatch"
        );
        let mut data = Vec::with_capacity(values.len() * T::DTYPE.size());
        for &v in values {
            v.write_le(&mut data);
        }
        Self {
            name: name.into(),
            shape,
            dtype: T::DTYPE,
            data,
        }
    }

    /// An `I64` tensor.
    pub fn from_i64(name: impl Into<String>, shape: Vec<usize>, values: &[i64]) -> Self {
        assert_eq!(
            shape.iter().product::<usize>(),
            values.len(),
            "tensor shape/value count mismatch"
        );
        let data = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        Self {
            name: name.into(),
            shape,
            dtype: Dtype::I64,
            data,
        }
    }

    /// The values as `T`, checking the dtype.
    pub fn values<T: Float>(&self) -> Result<Vec<T>, NnError> {
        self.check_dtype(T::DTYPE)?;
        Ok(self
            .data
            .chunks_exact(T::DTYPE.size())
            .map(T::read_le)
            .collect())
    }

    /// Copies the values into `out` (same length), checking the dtype.
    pub fn copy_into<T: Float>(&self, out: &mut [T]) -> Result<(), NnError> {
        self.check_dtype(T::DTYPE)?;
        let n = self.data.len() / T::DTYPE.size();
        if n != out.len() {
            return Err(NnError::ShapeMismatch {
                name: self.name.clone(),
                expected: vec![out.len()],
                found: self.shape.clone(),
            });
        }
        for (o, b) in out.iter_mut().zip(self.data.chunks_exact(T::DTYPE.size())) {
            *o = T::read_le(b);
        }
        Ok(())
    }

    fn check_dtype(&self, expected: Dtype) -> Result<(), NnError> {
        if self.dtype != expected {
            return Err(NnError::DtypeMismatch {
                name: self.name.clone(),
                expected: expected.to_string(),
                found: self.dtype.to_string(),
            });
        }
        Ok(())
    }
}

/// Encodes tensors (names must be unique) and string metadata as safetensors bytes.
pub fn to_safetensors(
    tensors: &[Tensor],
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<u8>, NnError> {
    let mut views = Vec::with_capacity(tensors.len());
    for t in tensors {
        let view = safetensors::tensor::TensorView::new(t.dtype.to_st(), t.shape.clone(), &t.data)
            .map_err(|e| NnError::Format(format!("tensor `{}`: {e}", t.name)))?;
        views.push((t.name.clone(), view));
    }
    let meta: HashMap<String, String> = metadata
        .iter()
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    safetensors::serialize(views, if meta.is_empty() { None } else { Some(meta) })
        .map_err(|e| NnError::Format(e.to_string()))
}

/// Writes tensors to a safetensors file (the write goes to `path.tmp` first, then is renamed, so
/// a crash never leaves a half-written checkpoint under the real name).
pub fn save_file(
    path: &Path,
    tensors: &[Tensor],
    metadata: &BTreeMap<String, String>,
) -> Result<(), NnError> {
    let bytes = to_safetensors(tensors, metadata)?;
    let io = |source| NnError::Io {
        path: path.display().to_string(),
        source,
    };
    let tmp = path.with_extension("safetensors.tmp");
    std::fs::write(&tmp, bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

/// A decoded safetensors file: tensors by name plus metadata.
#[derive(Clone, Debug, Default)]
pub struct TensorFile {
    pub tensors: BTreeMap<String, Tensor>,
    pub metadata: BTreeMap<String, String>,
}

impl TensorFile {
    /// Decodes safetensors bytes; tensors of dtypes other than F32/F64/I64 are an error.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, NnError> {
        let (_, meta) = safetensors::SafeTensors::read_metadata(bytes)
            .map_err(|e| NnError::Format(e.to_string()))?;
        let st = safetensors::SafeTensors::deserialize(bytes)
            .map_err(|e| NnError::Format(e.to_string()))?;
        let mut tensors = BTreeMap::new();
        for (name, view) in st.tensors() {
            let dtype = Dtype::from_st(view.dtype()).ok_or_else(|| {
                NnError::Format(format!(
                    "tensor `{name}` has unsupported dtype {}",
                    view.dtype()
                ))
            })?;
            let t = Tensor {
                name: name.clone(),
                shape: view.shape().to_vec(),
                dtype,
                data: view.data().to_vec(),
            };
            tensors.insert(name, t);
        }
        let metadata = meta
            .metadata()
            .clone()
            .unwrap_or_default()
            .into_iter()
            .collect();
        Ok(Self { tensors, metadata })
    }

    /// Reads and decodes a safetensors file.
    pub fn load(path: &Path) -> Result<Self, NnError> {
        let bytes = std::fs::read(path).map_err(|source| NnError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_bytes(&bytes)
    }

    /// Builds a file from in-memory tensors (for example weights received over the network).
    pub fn from_tensors(tensors: impl IntoIterator<Item = Tensor>) -> Self {
        Self {
            tensors: tensors.into_iter().map(|t| (t.name.clone(), t)).collect(),
            metadata: BTreeMap::new(),
        }
    }

    /// The tensor `name`, which must have exactly `shape`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<&Tensor, NnError> {
        let t = self
            .tensors
            .get(name)
            .ok_or_else(|| NnError::MissingTensor {
                name: name.to_string(),
            })?;
        if t.shape != shape {
            return Err(NnError::ShapeMismatch {
                name: name.to_string(),
                expected: shape.to_vec(),
                found: t.shape.clone(),
            });
        }
        Ok(t)
    }

    /// The values of float tensor `name`, checking shape and dtype.
    pub fn values<T: Float>(&self, name: &str, shape: &[usize]) -> Result<Vec<T>, NnError> {
        self.get(name, shape)?.values()
    }

    /// The values of `I64` tensor `name`, checking shape and dtype.
    pub fn i64_values(&self, name: &str, shape: &[usize]) -> Result<Vec<i64>, NnError> {
        let t = self.get(name, shape)?;
        t.check_dtype(Dtype::I64)?;
        Ok(t.data
            .chunks_exact(8)
            .map(|b| i64::from_le_bytes(b.try_into().expect("8 bytes")))
            .collect())
    }
}
