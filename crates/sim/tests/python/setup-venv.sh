#!/usr/bin/env bash
# Creates the Python venv that the terl-sim rendering test (tests/render.rs) uses as its second
# path: Python MuJoCo 3.3.7's own `mujoco.Renderer` on its own EGL backend (PyOpenGL), drawing the
# same model, state and camera as terl's renderer.
#
# Idempotent: does nothing when the venv already has the pinned packages. Location:
# .deps/render-venv at the repository root (git-ignored).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)"
VENV="$ROOT/.deps/render-venv"
PACKAGES=("mujoco==3.3.7" "PyOpenGL==3.1.10" "numpy==2.4.6")
CHECK="import importlib.metadata as m
import mujoco, OpenGL, numpy
assert m.version('mujoco') == '3.3.7', m.version('mujoco')
assert m.version('PyOpenGL') == '3.1.10', m.version('PyOpenGL')"

if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "$CHECK" 2>/dev/null; then
    echo "render-venv: ready at $VENV"
    exit 0
fi
echo "render-venv: creating $VENV"
python3 -m venv "$VENV" || {
    echo "render-venv: python3 -m venv failed; install python3-venv (apt-get install python3-venv)" >&2
    exit 1
}
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet "${PACKAGES[@]}"
"$VENV/bin/python" -c "$CHECK"
echo "render-venv: ready at $VENV"
