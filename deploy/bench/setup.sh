#!/usr/bin/env bash
# Creates .deps/bench-venv, the Python environment with PyTorch (CPU is enough) that
# compare_sac.sh and compare_tep.sh run the reference updates in. Not part of deploy/setup.sh:
# the tests do not need it, and the PyTorch wheel is a large download.
#   deploy/bench/setup.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
VENV=.deps/bench-venv
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
"$VENV/bin/pip" install -q --upgrade pip
"$VENV/bin/pip" install -q torch numpy
"$VENV/bin/python" -c 'import torch; print("torch", torch.__version__, "cpu", torch.backends.cpu.get_cpu_capability())'
