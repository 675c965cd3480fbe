#!/usr/bin/env bash
# Create (or refresh) the Python venv used to record Meta-World parity traces.
#
#   tests/parity/setup-venv.sh            # -> <repo>/.deps/venv
#
# Idempotent: a re-run with everything in place only verifies the imports. Installs numpy, scipy,
# gymnasium>=1.1, imageio, packaging (gymnasium.envs.mujoco imports it), mujoco==3.3.7 and
# metaworld==3.1.1. metaworld is installed with --no-deps because it pins mujoco==3.3.0 and we
# deliberately run MuJoCo 3.3.7 (the version the Rust sim crate links). The wheels downloaded by
# deploy/setup.sh (.deps/wheels) are preferred; anything missing is fetched with pip.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
DEPS="$ROOT/.deps"
VENV="$DEPS/venv"
WHEELS="$DEPS/wheels"
MUJOCO_VERSION=3.3.7
METAWORLD_VERSION=3.1.1
PYTHON=${PYTHON:-python3}

say() { printf '[setup-venv] %s\n' "$*" >&2; }
die() {
    printf '[setup-venv] ERROR: %s\n' "$1" >&2
    [ $# -gt 1 ] && printf '[setup-venv] fix: %s\n' "$2" >&2
    exit 1
}

check() {
    "$VENV/bin/python" - "$MUJOCO_VERSION" "$METAWORLD_VERSION" <<'PY'
import sys
from importlib.metadata import version
mjv, mwv = sys.argv[1:3]
import packaging, numpy, scipy, gymnasium, imageio, mujoco, metaworld, metaworld.policies  # noqa: F401
assert mujoco.__version__ == mjv, f"mujoco {mujoco.__version__} != {mjv}"
assert version("metaworld") == mwv, f"metaworld {version('metaworld')} != {mwv}"
gv = tuple(int(x) for x in gymnasium.__version__.split(".")[:2])
assert gv >= (1, 1), f"gymnasium {gymnasium.__version__} < 1.1"
PY
}

command -v "$PYTHON" >/dev/null || die "$PYTHON not found" "install Python 3.10-3.13 or set PYTHON=/path/to/python3"
"$PYTHON" -c 'import sys; sys.exit(not ((3, 10) <= sys.version_info[:2] <= (3, 13)))' \
    || die "$($PYTHON --version 2>&1) is not supported by metaworld $METAWORLD_VERSION" \
        "use Python 3.10-3.13 (set PYTHON=/path/to/python3)"

if [ -x "$VENV/bin/python" ] && check 2>/dev/null; then
    say "venv already complete: $VENV"
    exit 0
fi

if [ ! -x "$VENV/bin/python" ]; then
    say "creating venv $VENV"
    mkdir -p "$DEPS" || die "cannot create $DEPS" "check permissions and free disk space"
    "$PYTHON" -m venv "$VENV" \
        || die "python -m venv failed" "install the venv module (apt-get install python3-venv) and re-run"
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check -q)

# Prefer the already-downloaded wheels, fall back to the package index.
wheel_or_spec() {
    local spec=$1 pattern=$2 w
    w=$(ls "$WHEELS"/$pattern 2>/dev/null | head -n1 || true)
    if [ -n "$w" ]; then echo "$w"; else echo "$spec"; fi
}
MJ=$(wheel_or_spec "mujoco==$MUJOCO_VERSION" "mujoco-$MUJOCO_VERSION-*.whl")
MW=$(wheel_or_spec "metaworld==$METAWORLD_VERSION" "metaworld-$METAWORLD_VERSION-*.whl")

say "installing numpy, scipy, gymnasium>=1.1, imageio, packaging, mujoco==$MUJOCO_VERSION"
"${PIP[@]}" install "numpy" "scipy>=1.4.1" "gymnasium>=1.1" "imageio" "packaging" "$MJ" \
    || die "pip could not install the runtime dependencies" \
        "check network access to the Python package index and free disk space (df -h $DEPS), then re-run"
say "installing metaworld==$METAWORLD_VERSION (--no-deps: keeps mujoco $MUJOCO_VERSION)"
"${PIP[@]}" install --no-deps "$MW" \
    || die "pip could not install metaworld $METAWORLD_VERSION" \
        "run ./deploy/setup.sh to download the wheel, or check network access, then re-run"

check || die "the venv does not import correctly (see the traceback above)" \
    "delete $VENV and re-run this script"
say "done: $VENV ($("$VENV/bin/python" -c 'import mujoco, numpy, gymnasium; print("mujoco", mujoco.__version__, "numpy", numpy.__version__, "gymnasium", gymnasium.__version__)'))"
