#!/usr/bin/env bash
# Creates the Python venv whose TensorBoard reads the event files terl writes (tests/tensorboard.rs
# here, and the cluster test that reads a live and a killed run's scalars): TensorBoard's own
# `event_accumulator`, the reader behind `tensorboard --logdir`.
#
# Idempotent: does nothing when the venv already has the pinned packages. Location:
# .deps/tensorboard-venv at the repository root (git-ignored).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)"
VENV="$ROOT/.deps/tensorboard-venv"
PACKAGES=("tensorboard==2.21.0" "protobuf==7.36.2" "numpy==2.4.6" "setuptools==65.5.0")
CHECK="import importlib.metadata as m
from tensorboard.backend.event_processing import event_accumulator
assert m.version('tensorboard') == '2.21.0', m.version('tensorboard')"

if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "$CHECK" 2>/dev/null; then
    echo "tensorboard-venv: ready at $VENV"
    exit 0
fi
echo "tensorboard-venv: creating $VENV"
python3 -m venv "$VENV" || {
    echo "tensorboard-venv: python3 -m venv failed; install python3-venv (apt-get install python3-venv)" >&2
    exit 1
}
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet "${PACKAGES[@]}"
"$VENV/bin/python" -c "$CHECK"
echo "tensorboard-venv: ready at $VENV"
