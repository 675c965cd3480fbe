//! Generates MuJoCo 3.3.7 bindings from the headers that `deploy/setup.sh` unpacks, as a table of
//! function pointers loaded at run time (`libloading`), and bakes the default locations of the
//! library and the Meta-World assets into the crate so binaries need no environment variables.
use std::env;
use std::path::{Path, PathBuf};

fn main() {
    let manifest = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap());
    let root = manifest.join("../..").canonicalize().unwrap();
    let mujoco_dir = env::var_os("TERL_MUJOCO_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join(".deps/mujoco"));
    let include = mujoco_dir.join("include");
    let header = include.join("mujoco/mujoco.h");
    println!("cargo:rerun-if-env-changed=TERL_MUJOCO_DIR");
    println!("cargo:rerun-if-changed={}", header.display());
    if !header.exists() {
        panic!(
            "MuJoCo 3.3.7 headers not found at {}: run ./deploy/setup.sh (or set TERL_MUJOCO_DIR \
             to a folder with include/mujoco/mujoco.h and lib/libmujoco.so)",
            include.display()
        );
    }
    let lib = mujoco_dir.join("lib/libmujoco.so");
    let assets = root.join("assets/metaworld");
    println!(
        "cargo:rustc-env=TERL_MUJOCO_LIB_DEFAULT={}",
        abs(&lib).display()
    );
    println!(
        "cargo:rustc-env=TERL_METAWORLD_ASSETS_DEFAULT={}",
        abs(&assets).display()
    );

    let bindings = bindgen::Builder::default()
        .header(header.to_string_lossy())
        .clang_arg(format!("-I{}", include.display()))
        .allowlist_function("mj_.*|mju_.*|mjs_getError|mjv_.*|mjr_.*")
        .allowlist_type("mj.*")
        .allowlist_var("mj.*")
        .blocklist_function("mju_user_.*")
        .dynamic_library_name("MuJoCoLib")
        .dynamic_link_require_all(true)
        .derive_default(true)
        .layout_tests(false)
        .generate_comments(false)
        .prepend_enum_name(false)
        .parse_callbacks(Box::new(bindgen::CargoCallbacks::new()))
        .generate()
        .expect("bindgen failed on mujoco.h");
    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("mujoco_bindings.rs");
    bindings.write_to_file(out).expect("cannot write bindings");
}

fn abs(p: &Path) -> PathBuf {
    p.canonicalize().unwrap_or_else(|_| p.to_path_buf())
}
