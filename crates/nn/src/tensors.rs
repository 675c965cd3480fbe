//! Named tensors and their safetensors encoding (8-byte little-endian header length, JSON header,
//! raw little-endian data), readable by PyTorch's `safetensors.torch.load_file` and other tools.
//!
//! Loading is strict: a tensor the caller asks for must exist with exactly the expected shape and
//! dtype, otherwise a [`NnError`] names the tensor and both shapes or dtypes.

use crate::error::NnError;
pub use crate::scalar::Dtype;
use crate::scalar::Float;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// The safetensors encoding of a [`Dtype`].
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
}

/// One named tensor with its data as little-endian bytes (row-major, C order).
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    /// Name of the tensor in the file (for example `{prefix}.m`).
    pub name: String,
    /// Dimensions, outermost first.
    pub shape: Vec<usize>,
    /// Element type of `data`.
    pub dtype: Dtype,
    /// Raw elements, little-endian, row-major; `shape.iter().product() * dtype.size()` bytes.
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

/// Encodes tensors (names must be unique) and string metadata as safetensors bytes. The same
/// tensors and metadata always give the same bytes: the header's keys are written in sorted
/// order (the safetensors crate takes the metadata as a `HashMap`, whose order changes from
/// process to process), so reproducible runs can be compared file against file.
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
    let mut bytes = safetensors::serialize(views, if meta.is_empty() { None } else { Some(meta) })
        .map_err(|e| NnError::Format(e.to_string()))?;
    canonical_header(&mut bytes)?;
    Ok(bytes)
}

/// Rewrites the JSON header of safetensors `bytes` in place with every object's keys sorted.
/// The same members in another order encode to the same length, and the header keeps its
/// space padding, so the data offsets do not move.
fn canonical_header(bytes: &mut [u8]) -> Result<(), NnError> {
    let bad = |what: &str| NnError::Format(format!("encoded safetensors header: {what}"));
    let len_bytes: [u8; 8] = bytes
        .get(..8)
        .and_then(|b| b.try_into().ok())
        .ok_or_else(|| bad("shorter than its length field"))?;
    let n = usize::try_from(u64::from_le_bytes(len_bytes)).map_err(|_| bad("length"))?;
    let header = bytes
        .get(8..8 + n)
        .ok_or_else(|| bad("longer than the file"))?;
    // `BTreeMap`s sort the keys of the header and of its `__metadata__` object.
    let parsed: BTreeMap<String, serde_json::Value> =
        serde_json::from_slice(header).map_err(|e| bad(&e.to_string()))?;
    let sorted: BTreeMap<&String, serde_json::Value> = parsed
        .iter()
        .map(|(k, v)| {
            let v = match v.as_object() {
                Some(o) => serde_json::to_value(o.iter().collect::<BTreeMap<_, _>>())
                    .map_err(|e| bad(&e.to_string()))?,
                None => v.clone(),
            };
            Ok((k, v))
        })
        .collect::<Result<_, NnError>>()?;
    let text = serde_json::to_vec(&sorted).map_err(|e| bad(&e.to_string()))?;
    if text.len() > n {
        return Err(bad("sorted header longer than the original"));
    }
    let out = &mut bytes[8..8 + n];
    out[..text.len()].copy_from_slice(&text);
    out[text.len()..].fill(b' ');
    Ok(())
}

/// Metadata key of the content checksum [`save_file`] writes and [`TensorFile::from_bytes`]
/// verifies: `crc32:` and eight hex digits, the CRC-32 of every tensor (sorted by name: name,
/// dtype, shape, data) and every other metadata entry, each length-prefixed.
pub const CHECKSUM_KEY: &str = "terl.checksum";
/// Metadata key of the file format version [`save_file`] writes.
pub const FORMAT_VERSION_KEY: &str = "terl.format_version";
/// The file format version this crate writes and the newest it reads.
pub const FORMAT_VERSION: u32 = 1;

/// The content checksum stored under [`CHECKSUM_KEY`] (see there).
fn content_checksum<'a>(
    tensors: impl IntoIterator<Item = &'a Tensor>,
    metadata: &BTreeMap<String, String>,
) -> String {
    let mut sorted: Vec<&Tensor> = tensors.into_iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    let mut h = crc32fast::Hasher::new();
    let mut field = |bytes: &[u8]| {
        h.update(&(bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    for t in sorted {
        field(t.name.as_bytes());
        field(t.dtype.to_string().as_bytes());
        let shape: Vec<u8> = t
            .shape
            .iter()
            .flat_map(|d| (*d as u64).to_le_bytes())
            .collect();
        field(&shape);
        field(&t.data);
    }
    for (k, v) in metadata.iter().filter(|(k, _)| *k != CHECKSUM_KEY) {
        field(k.as_bytes());
        field(v.as_bytes());
    }
    format!("crc32:{:08x}", h.finalize())
}

/// Most bytes of a safetensors header this crate reads (the format's own limit: 100 MB).
pub const MAX_HEADER_BYTES: u64 = 100_000_000;

/// The tensor data bytes a safetensors JSON header describes: the largest end offset of its
/// tensors (`data_offsets`), 0 for none.
fn header_data_len(header: &[u8]) -> Result<u64, NnError> {
    let bad = |m: &str| NnError::Format(format!("safetensors header: {m}"));
    let json: serde_json::Value =
        serde_json::from_slice(header).map_err(|e| bad(&format!("invalid JSON ({e})")))?;
    let entries = json.as_object().ok_or_else(|| bad("not a JSON object"))?;
    let mut end = 0u64;
    for (name, entry) in entries {
        if name == "__metadata__" {
            continue;
        }
        let offsets = entry
            .get("data_offsets")
            .and_then(|o| o.as_array())
            .filter(|o| o.len() == 2)
            .and_then(|o| Some((o[0].as_u64()?, o[1].as_u64()?)))
            .ok_or_else(|| bad(&format!("tensor `{name}` has no valid data_offsets")))?;
        if offsets.0 > offsets.1 {
            return Err(bad(&format!("tensor `{name}` ends before it starts")));
        }
        end = end.max(offsets.1);
    }
    Ok(end)
}

/// Writes tensors to a safetensors file durably and atomically, with a format version
/// ([`FORMAT_VERSION_KEY`]) and a content checksum ([`CHECKSUM_KEY`]) added to `metadata`.
///
/// The bytes go to `<path>.tmp` first, which is flushed to disk (`fsync`), renamed to `path`, and
/// then the folder is flushed too, so after a crash or power loss the real name holds either
/// the previous file or the complete new one, never half a file.
///
/// # Errors
/// [`NnError::Io`] naming the file (for example a full disk; the temporary file is removed and
/// an earlier file under `path` is left as it was), [`NnError::Format`] for invalid tensors.
pub fn save_file(
    path: &Path,
    tensors: &[Tensor],
    metadata: &BTreeMap<String, String>,
) -> Result<(), NnError> {
    use std::io::Write;
    let mut metadata = metadata.clone();
    metadata
        .entry(FORMAT_VERSION_KEY.to_string())
        .or_insert_with(|| FORMAT_VERSION.to_string());
    metadata.insert(
        CHECKSUM_KEY.to_string(),
        content_checksum(tensors, &metadata),
    );
    let bytes = to_safetensors(tensors, &metadata)?;
    let mut tmp_name = path.as_os_str().to_owned();
    tmp_name.push(".tmp");
    let tmp = std::path::PathBuf::from(tmp_name);
    let io = |at: &Path| {
        let at = at.display().to_string();
        move |source| NnError::Io { path: at, source }
    };
    let written = std::fs::File::create(&tmp)
        .and_then(|mut f| {
            f.write_all(&bytes)?;
            f.sync_all()
        })
        .map_err(io(&tmp));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path).map_err(io(path))?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    // Flushing the folder makes the rename itself durable (not supported on every platform).
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

/// A decoded safetensors file: tensors by name plus metadata.
#[derive(Clone, Debug, Default)]
pub struct TensorFile {
    /// The tensors, keyed by name.
    pub tensors: BTreeMap<String, Tensor>,
    /// The file's string metadata (including [`CHECKSUM_KEY`] and [`FORMAT_VERSION_KEY`] when written by [`save_file`]).
    pub metadata: BTreeMap<String, String>,
}

impl TensorFile {
    /// Decodes safetensors bytes.
    ///
    /// Errors: [`NnError::Format`] for bytes that are not a file this crate reads (cut short, a
    /// header length past the end or above safetensors' header limit, bad JSON, shapes or offsets
    /// that do not match the data, a dtype other than F32/F64/I64, a newer format version, or a
    /// file whose checksum key is damaged); [`NnError::Checksum`] when the content
    /// does not match the stored checksum. Nothing is allocated beyond what `bytes` holds.
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
        let metadata: BTreeMap<String, String> = meta
            .metadata()
            .clone()
            .unwrap_or_default()
            .into_iter()
            .collect();
        if let Some(v) = metadata.get(FORMAT_VERSION_KEY) {
            match v.parse::<u32>() {
                Ok(v) if v <= FORMAT_VERSION => {}
                _ => {
                    return Err(NnError::Format(format!(
                        "format version {v:?} is not one this build reads (up to {FORMAT_VERSION})"
                    )))
                }
            }
        }
        match metadata.get(CHECKSUM_KEY) {
            Some(stored) => {
                let computed = content_checksum(tensors.values(), &metadata);
                if *stored != computed {
                    return Err(NnError::Checksum {
                        stored: stored.clone(),
                        computed,
                    });
                }
            }
            // Files of save_file carry both keys; only files from before checksums have neither.
            // A versioned file without its checksum, or remains of the keys (a damaged name, two
            // keys run together, the checksum's value under another name), is a damaged file
            // whose content cannot be trusted unverified.
            None if metadata.iter().any(|(k, v)| {
                k.contains("checksum") || k.contains("format_version") || v.starts_with("crc32:")
            }) =>
            {
                return Err(NnError::Format(format!(
                    "metadata has no {CHECKSUM_KEY} but remains of it or of \
                     {FORMAT_VERSION_KEY}: the file's header is damaged"
                )))
            }
            None => {}
        }
        Ok(Self { tensors, metadata })
    }

    /// Reads and decodes a safetensors file.
    pub fn load(path: &Path) -> Result<Self, NnError> {
        use std::io::Read;
        let io = |source| NnError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut file = std::fs::File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        // The layout is checked against the file's size before the data is read, so a damaged or
        // foreign file (a huge one included) is refused after reading its header only.
        let mut len = [0u8; 8];
        file.read_exact(&mut len)
            .map_err(|_| NnError::Format(format!("{file_len} bytes: no safetensors header")))?;
        let header_len = u64::from_le_bytes(len);
        if header_len > MAX_HEADER_BYTES || header_len > file_len.saturating_sub(8) {
            return Err(NnError::Format(format!(
                "header of {header_len} bytes does not fit (file of {file_len} bytes, headers of \
                 at most {MAX_HEADER_BYTES})"
            )));
        }
        let mut header = vec![0u8; header_len as usize];
        file.read_exact(&mut header).map_err(io)?;
        let data_len = header_data_len(&header)?;
        if 8 + header_len + data_len != file_len {
            return Err(NnError::Format(format!(
                "the header describes {data_len} bytes of tensor data after its {header_len} \
                 bytes, but the file has {} (cut or padded)",
                file_len.saturating_sub(8 + header_len)
            )));
        }
        let mut bytes = Vec::with_capacity(file_len as usize);
        bytes.extend_from_slice(&len);
        bytes.extend_from_slice(&header);
        file.read_to_end(&mut bytes).map_err(io)?;
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
