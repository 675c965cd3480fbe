#!/usr/bin/env bash
# One-time (and idempotent) setup for terl on a fresh Linux machine.
#
# - installs the native build prerequisites (a C toolchain, libclang for bindgen);
# - downloads the mujoco==3.3.7 and metaworld==3.1.1 wheels with pip (as plain archives, no
#   dependency resolution) and unpacks libmujoco + headers into .deps/mujoco and the Meta-World
#   XML/STL assets into assets/metaworld;
# - records what it did in .deps/setup.done so a re-run is instant and works offline.
#
# - installs what `terl render` needs: EGL and Mesa's OpenGL (headless rendering), ffmpeg;
# - installs cargo-nextest when missing (the test runner of deploy/test.sh);
# - creates the Python environments the tests use (.deps/grpc-venv, .deps/mcap-venv,
#   .deps/k8s-venv, .deps/rliable-venv, .deps/render-venv, .deps/tensorboard-venv);
#   `--no-test-tools` skips them (the container image's build stage);
# - with `--container`, installs podman, runc and debootstrap: building the container image from
#   Debian packages when no image registry is reachable, and running it (deploy/container/).
#
# Nothing else is needed: the sim crate bakes the absolute path of .deps/mujoco/lib into every
# binary it builds (override at run time with TERL_MUJOCO_LIB=/path/to/libmujoco.so).
set -euo pipefail
test_tools=1
container_tools=0
for arg in "$@"; do
    case "$arg" in
        --no-test-tools) test_tools=0 ;;
        --container) container_tools=1 ;;
        *) echo "usage: $0 [--no-test-tools] [--container]" >&2; exit 2 ;;
    esac
done

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
DEPS="$ROOT/.deps"
MUJOCO_VERSION=3.3.7
METAWORLD_VERSION=3.1.1
STAMP="$DEPS/setup.done"
STAMP_CONTENT="mujoco=$MUJOCO_VERSION metaworld=$METAWORLD_VERSION layout=1"

say() { printf '[setup] %s\n' "$*" >&2; }
die() {
    printf '[setup] ERROR: %s\n' "$1" >&2
    [ $# -gt 1 ] && printf '[setup] fix: %s\n' "$2" >&2
    exit 1
}

if [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "$STAMP_CONTENT" ] \
    && [ -e "$DEPS/mujoco/lib/libmujoco.so" ] && [ -f "$ROOT/assets/metaworld/sawyer_xyz/sawyer_reach_v3.xml" ]; then
    have_all=1
else
    have_all=0
fi

# ---------------------------------------------------------------- system packages
as_root() {
    if [ "$(id -u)" -eq 0 ]; then "$@"; elif command -v sudo >/dev/null; then sudo "$@"; else
        die "need root to run: $*" "run this script as root or install sudo"
    fi
}
apt_install() {
    command -v apt-get >/dev/null || die "missing system packages: $*" \
        "install them with your distribution's package manager, then re-run ./deploy/setup.sh"
    say "installing system packages: $*"
    if ! as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "$@" >/dev/null 2>&1; then
        as_root env DEBIAN_FRONTEND=noninteractive apt-get update -q >/dev/null 2>&1 || true
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -q "$@" >/dev/null \
            || die "could not install $*" "check network access to the Debian package mirror, then re-run"
    fi
}

have_libclang() {
    [ -n "${LIBCLANG_PATH:-}" ] && return 0
    ls /usr/lib/llvm-*/lib/libclang.so* /usr/lib/x86_64-linux-gnu/libclang*.so* 2>/dev/null | grep -q libclang
}

need=()
command -v cc >/dev/null || need+=(build-essential)
have_libclang || need+=(libclang-dev)
command -v python3 >/dev/null || need+=(python3 python3-pip)
# `terl report` draws PNG charts with DejaVu Sans (plotters renders text from a font file).
font_found=0
for f in /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf /usr/share/fonts/dejavu/DejaVuSans.ttf \
    /usr/share/fonts/TTF/DejaVuSans.ttf; do [ -f "$f" ] && font_found=1; done
[ "$font_found" = 1 ] || need+=(fonts-dejavu-core)
# `terl render`: a headless OpenGL context (EGL on Mesa's software rasteriser, no display) and
# ffmpeg for the MP4 videos (and ffprobe for their test).
have_deb() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q 'ok installed'; }
if command -v dpkg-query >/dev/null; then
    for p in libegl1 libegl-mesa0 libgl1-mesa-dri; do have_deb "$p" || need+=("$p"); done
fi
command -v ffmpeg >/dev/null && command -v ffprobe >/dev/null || need+=(ffmpeg)
[ ${#need[@]} -eq 0 ] || apt_install "${need[@]}"
command -v cargo >/dev/null || die "cargo not found" "install the stable Rust toolchain (rustup), then re-run"

# ---------------------------------------------------------------- gRPC interop client (crates/wire)
# The terl-wire tests use Python's grpcio-reflection and grpcio-health-checking as a gRPC client we
# did not write; their venv lives in .deps/grpc-venv. The script is idempotent (instant when done).
setup_grpc_venv() {
    python3 -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
    "$ROOT/crates/wire/tests/python/setup-venv.sh" >&2 \
        || die "creating .deps/grpc-venv failed" "re-run crates/wire/tests/python/setup-venv.sh and read its output"
}

# ---------------------------------------------------------------- MCAP interop reader (crates/telemetry)
# The terl-telemetry tests read our MCAP files back with the official Python `mcap` reader and
# `mcap-protobuf-support`; their venv lives in .deps/mcap-venv. Idempotent (instant when done).
setup_mcap_venv() {
    python3 -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
    "$ROOT/crates/telemetry/tests/python/setup-venv.sh" >&2 \
        || die "creating .deps/mcap-venv failed" "re-run crates/telemetry/tests/python/setup-venv.sh and read its output"
}

# ---------------------------------------------------------------- rliable (crates/stats)
# The terl-stats test compares the crate's IQM, mean, probability of improvement and bootstrap
# intervals with rliable's on the same scores; its venv lives in .deps/rliable-venv. Idempotent.
setup_rliable_venv() {
    python3 -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
    "$ROOT/crates/stats/tests/python/setup-venv.sh" >&2 \
        || die "creating .deps/rliable-venv failed" "re-run crates/stats/tests/python/setup-venv.sh and read its output"
}

# Python MuJoCo's own renderer (the second path of crates/sim/tests/render.rs).
setup_render_venv() {
    python3 -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
    "$ROOT/crates/sim/tests/python/setup-venv.sh" >&2 \
        || die "creating .deps/render-venv failed" "re-run crates/sim/tests/python/setup-venv.sh and read its output"
}

# TensorBoard's own reader of the event files terl writes (crates/telemetry/tests, cluster tests).
setup_tensorboard_venv() {
    python3 -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
    "$ROOT/crates/telemetry/tests/python/setup-tensorboard-venv.sh" >&2 \
        || die "creating .deps/tensorboard-venv failed" "re-run crates/telemetry/tests/python/setup-tensorboard-venv.sh and read its output"
}

setup_k8s_venv() {
    python3 -c "import ensurepip, venv" 2>/dev/null || apt_install python3-venv
    "$ROOT/deploy/k8s/setup-validator.sh" >&2 \
        || die "creating .deps/k8s-venv failed" "re-run deploy/k8s/setup-validator.sh and read its output"
}

# cargo-nextest runs the tests (deploy/test.sh): one process per test, and the test groups of
# .config/nextest.toml that keep the shared-memory tests apart. Built once when missing.
setup_nextest() {
    cargo nextest --version >/dev/null 2>&1 && return 0
    say "installing cargo-nextest (once; a few minutes)"
    cargo install --locked cargo-nextest >&2 \
        || die "installing cargo-nextest failed" "run: cargo install --locked cargo-nextest"
}

setup_test_tools() {
    [ "$test_tools" = 1 ] || return 0
    setup_nextest
    setup_grpc_venv
    setup_mcap_venv
    setup_k8s_venv
    setup_rliable_venv
    setup_render_venv
    setup_tensorboard_venv
}

# podman (with runc: Debian's default crun fails on hosts with hybrid cgroups) and debootstrap
# for the container image (deploy/container/build.sh); the podman settings are in
# deploy/container/containers.conf.
setup_container_tools() {
    [ "$container_tools" = 1 ] || return 0
    local missing=()
    for p in podman runc debootstrap; do command -v "$p" >/dev/null || missing+=("$p"); done
    [ ${#missing[@]} -eq 0 ] || apt_install "${missing[@]}"
}
setup_container_tools

[ "$have_all" = 1 ] && { say "already set up ($STAMP_CONTENT)"; setup_test_tools; exit 0; }

# ---------------------------------------------------------------- wheels
python3 -m pip --version >/dev/null 2>&1 || die "python3 has no pip" "install python3-pip (apt-get install python3-pip)"
mkdir -p "$DEPS/wheels" || die "cannot create $DEPS" "check permissions and free disk space"
fetch_wheel() {
    local spec=$1 pattern=$2
    if ls "$DEPS/wheels/"$pattern >/dev/null 2>&1; then return 0; fi
    say "downloading $spec"
    python3 -m pip download --no-deps --only-binary=:all: -q -d "$DEPS/wheels" "$spec" \
        || die "pip could not download $spec" \
            "check network access to the Python package index and free disk space (df -h $DEPS), then re-run"
}
fetch_wheel "mujoco==$MUJOCO_VERSION" "mujoco-$MUJOCO_VERSION-*.whl"
fetch_wheel "metaworld==$METAWORLD_VERSION" "metaworld-$METAWORLD_VERSION-*.whl"

# ---------------------------------------------------------------- unpack
say "unpacking libmujoco $MUJOCO_VERSION and Meta-World $METAWORLD_VERSION assets"
rm -rf "$DEPS/mujoco.tmp" "$ROOT/assets/metaworld.tmp"
python3 - "$DEPS" "$ROOT/assets" "$MUJOCO_VERSION" "$METAWORLD_VERSION" <<'PY' || die "unpacking failed" "free disk space (df -h), delete .deps/wheels and re-run"
import glob, os, sys, zipfile
deps, assets, mjv, mwv = sys.argv[1:5]
mj = glob.glob(os.path.join(deps, "wheels", f"mujoco-{mjv}-*.whl"))[0]
mw = glob.glob(os.path.join(deps, "wheels", f"metaworld-{mwv}-*.whl"))[0]
out = os.path.join(deps, "mujoco.tmp")
with zipfile.ZipFile(mj) as z:
    for name in z.namelist():
        if name.startswith("mujoco/include/mujoco/") and name.endswith(".h"):
            dst = os.path.join(out, "include", "mujoco", os.path.basename(name))
        elif name == f"mujoco/libmujoco.so.{mjv}":
            dst = os.path.join(out, "lib", os.path.basename(name))
        else:
            continue
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        with z.open(name) as src, open(dst, "wb") as f:
            f.write(src.read())
out = os.path.join(assets, "metaworld.tmp")
with zipfile.ZipFile(mw) as z:
    for name in z.namelist():
        if not name.startswith("metaworld/assets/") or name.endswith("/"):
            continue
        dst = os.path.join(out, name[len("metaworld/assets/"):])
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        with z.open(name) as src, open(dst, "wb") as f:
            f.write(src.read())
PY
ln -sf "libmujoco.so.$MUJOCO_VERSION" "$DEPS/mujoco.tmp/lib/libmujoco.so"
rm -rf "$DEPS/mujoco" "$ROOT/assets/metaworld"
mv "$DEPS/mujoco.tmp" "$DEPS/mujoco"
mv "$ROOT/assets/metaworld.tmp" "$ROOT/assets/metaworld"
echo "$STAMP_CONTENT" >"$STAMP"
say "done: libmujoco in .deps/mujoco/lib, Meta-World assets in assets/metaworld"

# gRPC interop client, MCAP reader, Kubernetes validator and rliable venvs (see setup_test_tools above).
setup_test_tools
