//! `TensorFile::from_bytes` on damaged safetensors bytes (random cuts, flipped bytes, huge
//! header lengths, overwritten words): never a panic or an allocation the bytes do not back;
//! a clear error, or, where the damage left the content intact (JSON whitespace), exactly the
//! tensors and metadata that were written.

use std::collections::BTreeMap;

use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use terl_nn::tensors::{save_file, to_safetensors, TensorFile};
use terl_nn::{Activation, Adam, AdamConfig, Mlp, MlpSpec, NnError, Tensor};

/// A real file as the learner writes it (through `save_file`: format version and checksum in
/// the metadata): a small network, its Adam state and an I64 counter tensor.
fn checkpoint_bytes() -> &'static [u8] {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES.get_or_init(|| {
        let spec = MlpSpec {
            input: 5,
            hidden: vec![8, 8],
            output: 3,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Identity,
        };
        let mlp: Mlp<f32> = Mlp::new(&spec, &mut ChaCha8Rng::seed_from_u64(3));
        let mut adam = Adam::<f32>::new(mlp.num_params(), AdamConfig::with_lr(1e-3));
        let mut p = mlp.params.clone();
        let g = vec![0.5; p.len()];
        adam.step(&mut p, &g);
        let mut tensors = Vec::new();
        mlp.export("policy", &mut tensors);
        adam.export("policy_adam", &mut tensors);
        tensors.push(Tensor::from_i64("counters", vec![2], &[12, 0]));
        let meta = BTreeMap::from([("terl.note".to_string(), "fuzz source".to_string())]);
        let dir = std::env::temp_dir().join(format!("terl-nn-damage-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("source.safetensors");
        save_file(&path, &tensors, &meta).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        bytes
    })
}

fn original() -> &'static TensorFile {
    static FILE: std::sync::OnceLock<TensorFile> = std::sync::OnceLock::new();
    FILE.get_or_init(|| TensorFile::from_bytes(checkpoint_bytes()).unwrap())
}

/// Decodes damaged bytes: an error that says what is wrong, or the original content.
fn check(bytes: &[u8]) -> Result<(), TestCaseError> {
    match TensorFile::from_bytes(bytes) {
        Ok(file) => {
            let want = original();
            prop_assert!(file.tensors == want.tensors, "damaged tensors decoded");
            prop_assert_eq!(&file.metadata, &want.metadata);
        }
        Err(e) => {
            prop_assert!(
                matches!(e, NnError::Format(_) | NnError::Checksum { .. }),
                "{e}"
            );
            prop_assert!(!e.to_string().is_empty());
        }
    }
    Ok(())
}

fn huge() -> impl Strategy<Value = u64> {
    prop_oneof![
        proptest::sample::select(vec![
            u64::MAX,
            4 << 60,
            1 << 40,
            100_000_001,
            u32::MAX as u64 + 1
        ]),
        any::<u64>(),
    ]
}

/// A fixed seed: the same cases on every run, so a failure is reproducible and CI is stable.
fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x7e71_0005),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config(400))]

    #[test]
    fn a_cut_file_is_an_error(cut in 0usize..100_000) {
        let bytes = checkpoint_bytes();
        let cut = cut % bytes.len();
        prop_assert!(TensorFile::from_bytes(&bytes[..cut]).is_err());
    }

    #[test]
    fn flipped_bytes_are_an_error_or_change_nothing(
        flips in proptest::collection::vec((0usize..100_000, 1u8..=255), 1..4)
    ) {
        let mut bytes = checkpoint_bytes().to_vec();
        for (at, mask) in flips {
            let n = bytes.len();
            bytes[at % n] ^= mask;
        }
        check(&bytes)?;
    }

    #[test]
    fn a_huge_header_length_is_an_error(len in huge()) {
        let mut bytes = checkpoint_bytes().to_vec();
        bytes[..8].copy_from_slice(&len.to_le_bytes());
        prop_assert!(TensorFile::from_bytes(&bytes).is_err());
    }

    /// A little-endian u64 written anywhere, or a huge decimal written over digits of the JSON
    /// header (a shape or an offset).
    #[test]
    fn overwritten_numbers_are_an_error_or_change_nothing(
        at in 0usize..100_000,
        value in huge(),
        as_text in any::<bool>(),
    ) {
        let mut bytes = checkpoint_bytes().to_vec();
        let header_end = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        if as_text {
            let digits = value.to_string();
            let at = 8 + at % (header_end - 8 - digits.len());
            bytes[at..at + digits.len()].copy_from_slice(digits.as_bytes());
        } else {
            let at = at % (bytes.len() - 8);
            bytes[at..at + 8].copy_from_slice(&value.to_le_bytes());
        }
        check(&bytes)?;
    }
}

/// Shapes whose element count overflows, or claims far more data than the file holds, are
/// refused before anything that size is allocated.
#[test]
fn huge_shapes_in_the_header_are_errors() {
    let good = to_safetensors(
        &[Tensor::from_values("w", vec![2, 2], &[1f32; 4])],
        &BTreeMap::new(),
    )
    .unwrap();
    let header_len = u64::from_le_bytes(good[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&good[8..8 + header_len]).unwrap();
    assert!(header.contains("[2,2]"), "{header}");
    for shape in [
        "[4294967296,4294967296]",
        "[18446744073709551615,2]",
        "[1000000000000,1]",
    ] {
        let forged = header.replace("[2,2]", shape);
        let mut bytes = (forged.len() as u64).to_le_bytes().to_vec();
        bytes.extend_from_slice(forged.as_bytes());
        bytes.extend_from_slice(&good[8 + header_len..]);
        let e = TensorFile::from_bytes(&bytes).unwrap_err();
        assert!(matches!(e, NnError::Format(_)), "{shape}: {e}");
    }
}

/// A file whose checksum key is damaged must not pass as an old file without a checksum (whose
/// content is taken unverified): found by the properties above.
#[test]
fn a_damaged_checksum_key_is_an_error() {
    let bytes = checkpoint_bytes();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&bytes[8..8 + header_len]).unwrap();
    for (from, to) in [
        ("terl.checksum", "terl.bhecksum"),
        ("\"terl.checksum\":\"", "\"terl.checksum-x\":\""),
        ("terl.format_version", "terl.format_versiom"),
    ] {
        let forged = header.replace(from, to);
        assert_ne!(forged, header);
        let mut damaged = (forged.len() as u64).to_le_bytes().to_vec();
        damaged.extend_from_slice(forged.as_bytes());
        damaged.extend_from_slice(&bytes[8 + header_len..]);
        let e = TensorFile::from_bytes(&damaged).unwrap_err();
        assert!(
            matches!(e, NnError::Format(_) | NnError::Checksum { .. }),
            "{from}: {e}"
        );
    }
    // A file from before checksums (neither key) still loads.
    let legacy = to_safetensors(
        &original().tensors.values().cloned().collect::<Vec<_>>(),
        &BTreeMap::from([("format".to_string(), "pt".to_string())]),
    )
    .unwrap();
    assert_eq!(
        TensorFile::from_bytes(&legacy).unwrap().tensors,
        original().tensors
    );
}

/// `TensorFile::load` checks the layout against the file's size before it reads the data: a cut
/// or padded file, or a header length past the end, is an error that names it, and a file that
/// is mostly a hole (a damaged multi-GB checkpoint) is refused from its header alone. An intact
/// file loads as `from_bytes` reads it.
#[test]
fn load_checks_the_layout_against_the_file_size_first() {
    let dir = std::env::temp_dir().join(format!("terl-nn-load-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bytes = checkpoint_bytes();
    let path = dir.join("c.safetensors");
    std::fs::write(&path, bytes).unwrap();
    let loaded = TensorFile::load(&path).unwrap();
    assert_eq!(loaded.metadata, original().metadata);
    assert_eq!(loaded.tensors.len(), original().tensors.len());
    let expect = |data: &[u8], what: &str| {
        std::fs::write(&path, data).unwrap();
        let e = TensorFile::load(&path).unwrap_err().to_string();
        assert!(e.contains(what), "{what}: {e}");
    };
    expect(&bytes[..bytes.len() - 1], "cut or padded");
    expect(&[bytes, &[0u8; 3][..]].concat(), "cut or padded");
    expect(&bytes[..5], "no safetensors header");
    let mut long_header = bytes.to_vec();
    long_header[..8].copy_from_slice(&(bytes.len() as u64).to_le_bytes());
    expect(&long_header, "does not fit");
    // A sparse 64 GiB file behind a valid header: refused without reading the hole.
    std::fs::write(&path, bytes).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&path)
        .unwrap()
        .set_len(64 << 30)
        .unwrap();
    let e = TensorFile::load(&path).unwrap_err().to_string();
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(e.contains("cut or padded"), "{e}");
}
