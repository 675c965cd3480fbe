//! Safetensors round trips and the errors on mismatched files.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use terl_nn::tensors::{to_safetensors, Tensor, TensorFile};
use terl_nn::{Activation, Adam, AdamConfig, Mlp, MlpSpec, NnError};

fn spec(hidden: usize) -> MlpSpec {
    MlpSpec {
        input: 4,
        hidden: vec![hidden, hidden],
        output: 2,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Identity,
    }
}

#[test]
fn weights_and_adam_state_round_trip_bit_exactly() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mlp: Mlp<f32> = Mlp::new(&spec(8), &mut rng);
    let mut adam = Adam::<f32>::new(mlp.num_params(), AdamConfig::with_lr(1e-3));
    let mut p = mlp.params.clone();
    let g = vec![0.1; p.len()];
    adam.step(&mut p, &g);
    let mut tensors = Vec::new();
    mlp.export("policy", &mut tensors);
    adam.export("policy_adam", &mut tensors);
    let meta = BTreeMap::from([("format".to_string(), "pt".to_string())]);
    let bytes = to_safetensors(&tensors, &meta).unwrap();
    let file = TensorFile::from_bytes(&bytes).unwrap();
    assert_eq!(file.metadata.get("format").map(String::as_str), Some("pt"));
    assert_eq!(file.tensors["policy.0.weight"].shape, vec![8, 4]);

    let mut other: Mlp<f32> = Mlp::new(&spec(8), &mut ChaCha8Rng::seed_from_u64(2));
    other.import("policy", &file).unwrap();
    assert_eq!(other.params, mlp.params);
    let mut adam2 = Adam::<f32>::new(mlp.num_params(), AdamConfig::with_lr(1e-3));
    adam2.import("policy_adam", &file).unwrap();
    assert_eq!(adam2.steps(), 1);
    let (mut a, mut b) = (p.clone(), p.clone());
    let g2 = vec![0.2; p.len()];
    adam.step(&mut a, &g2);
    adam2.step(&mut b, &g2);
    assert_eq!(a, b);
}

#[test]
fn shape_dtype_and_missing_tensor_errors_name_the_tensor() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let small: Mlp<f32> = Mlp::new(&spec(8), &mut rng);
    let mut tensors = Vec::new();
    small.export("q", &mut tensors);
    let file = TensorFile::from_tensors(tensors.clone());

    let mut big: Mlp<f32> = Mlp::new(&spec(16), &mut rng);
    let before = big.params.clone();
    match big.import("q", &file) {
        Err(NnError::ShapeMismatch {
            name,
            expected,
            found,
        }) => {
            assert_eq!(name, "q.0.weight");
            assert_eq!((expected, found), (vec![16, 4], vec![8, 4]));
        }
        other => panic!("expected a shape mismatch, got {other:?}"),
    }
    assert_eq!(
        big.params, before,
        "a failed load must not change the weights"
    );

    let mut as_f64: Mlp<f64> = Mlp::new(&spec(8), &mut rng);
    let err = as_f64.import("q", &file).unwrap_err();
    assert!(matches!(err, NnError::DtypeMismatch { .. }), "{err}");
    assert!(err.to_string().contains("expected F64"), "{err}");

    let err = small.clone().import("pi", &file).unwrap_err();
    assert!(
        matches!(err, NnError::MissingTensor { ref name } if name == "pi.0.weight"),
        "{err}"
    );

    let mut bad = tensors;
    bad[0] = Tensor::from_values("q.0.weight", vec![8, 4], &[f32::NAN; 32]);
    let err = small
        .clone()
        .import("q", &TensorFile::from_tensors(bad))
        .unwrap_err();
    assert!(matches!(err, NnError::InvalidValue(_)), "{err}");

    assert!(matches!(
        TensorFile::from_bytes(b"not a file"),
        Err(NnError::Format(_))
    ));
}

/// A saved file carries a format version and a checksum; a flipped data byte, a flipped
/// metadata byte and a cut are each detected, and no temporary file is left behind.
#[test]
fn saved_files_detect_flipped_bytes_and_cuts() {
    use terl_nn::tensors::{save_file, CHECKSUM_KEY, FORMAT_VERSION_KEY};
    let dir = std::env::temp_dir().join(format!("terl-nn-checksum-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("net.safetensors");
    let mlp: Mlp<f32> = Mlp::new(&spec(8), &mut ChaCha8Rng::seed_from_u64(3));
    let mut tensors = Vec::new();
    mlp.export("policy", &mut tensors);
    let meta = BTreeMap::from([("terl.note".to_string(), "abc".to_string())]);
    save_file(&path, &tensors, &meta).unwrap();
    let names: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names, vec![std::ffi::OsString::from("net.safetensors")]);
    let bytes = std::fs::read(&path).unwrap();
    let file = TensorFile::from_bytes(&bytes).unwrap();
    assert!(file.metadata[CHECKSUM_KEY].starts_with("crc32:"));
    assert_eq!(file.metadata[FORMAT_VERSION_KEY], "1");
    let mut back: Mlp<f32> = Mlp::new(&spec(8), &mut ChaCha8Rng::seed_from_u64(4));
    back.import("policy", &file).unwrap();
    assert_eq!(back.params, mlp.params);

    // The last byte is weight data: flipping it keeps the file parseable, so only the
    // checksum can tell.
    let mut flipped = bytes.clone();
    *flipped.last_mut().unwrap() ^= 0x40;
    assert!(matches!(
        TensorFile::from_bytes(&flipped),
        Err(NnError::Checksum { .. })
    ));
    // A metadata value changed in place (same length, header still valid JSON).
    let at = bytes.windows(3).position(|w| w == b"abc").unwrap();
    let mut edited = bytes.clone();
    edited[at] = b'x';
    assert!(matches!(
        TensorFile::from_bytes(&edited),
        Err(NnError::Checksum { .. })
    ));
    for cut in [bytes.len() - 1, bytes.len() / 2, 9, 3] {
        assert!(
            TensorFile::from_bytes(&bytes[..cut]).is_err(),
            "cut at {cut}"
        );
    }
    // Files without a checksum (written before it existed, or by other tools) still load.
    let plain = to_safetensors(&tensors, &BTreeMap::new()).unwrap();
    TensorFile::from_bytes(&plain).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A file from a newer format version is refused with a message saying so.
#[test]
fn newer_format_versions_are_refused() {
    use terl_nn::tensors::FORMAT_VERSION_KEY;
    let mlp: Mlp<f32> = Mlp::new(&spec(4), &mut ChaCha8Rng::seed_from_u64(5));
    let mut tensors = Vec::new();
    mlp.export("policy", &mut tensors);
    let meta = BTreeMap::from([(FORMAT_VERSION_KEY.to_string(), "99".to_string())]);
    let bytes = to_safetensors(&tensors, &meta).unwrap();
    let err = TensorFile::from_bytes(&bytes).unwrap_err().to_string();
    assert!(
        err.contains("format version") && err.contains("99"),
        "{err}"
    );
}

/// The same tensors and metadata encode to the same bytes every time (the header's keys sorted,
/// not in a hash map's per-process order), and the sorted file reads back.
#[test]
fn encoding_is_the_same_bytes_every_time_with_sorted_header_keys() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mlp: Mlp<f32> = Mlp::new(&spec(8), &mut rng);
    let mut tensors = Vec::new();
    mlp.export("policy", &mut tensors);
    let meta: BTreeMap<String, String> = (0..24)
        .map(|k| (format!("key.{k:02}"), format!("value {k}")))
        .collect();
    let first = to_safetensors(&tensors, &meta).unwrap();
    for _ in 0..16 {
        assert_eq!(to_safetensors(&tensors, &meta).unwrap(), first);
    }
    let n = u64::from_le_bytes(first[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&first[8..8 + n]).unwrap();
    let positions: Vec<usize> = meta
        .keys()
        .map(|k| header.find(k.as_str()).unwrap())
        .collect();
    assert!(positions.windows(2).all(|w| w[0] < w[1]), "{header}");
    let back = TensorFile::from_bytes(&first).unwrap();
    assert_eq!(back.metadata, meta);
}
