#!/usr/bin/env bash
# Creates the Python environments of the benchmarks' references. Not part of deploy/setup.sh:
# the tests do not need them, and the PyTorch wheel is a large download.
#   deploy/bench/setup.sh              both
#   deploy/bench/setup.sh --metaworld  only .deps/metaworld-venv
# - .deps/bench-venv: PyTorch (CPU is enough), for compare_sac.sh and compare_tep.sh;
# - .deps/metaworld-venv: Python Meta-World 3.1.1 on MuJoCo 3.3.7 (metaworld 3.1.1 asks for
#   mujoco 3.3.0; its code runs on the 3.3.7 this project pins), for metaworld_python.py.
set -euo pipefail
cd "$(dirname "$0")/../.."
only_metaworld=0
while [ $# -gt 0 ]; do
    case "$1" in
        --metaworld) only_metaworld=1; shift ;;
        -h|--help) sed -n '2,8p' "$0"; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
venv() {
    [ -x "$1/bin/python" ] || python3 -m venv "$1"
    "$1/bin/pip" install -q --upgrade pip
}
MW=.deps/metaworld-venv
venv "$MW"
"$MW/bin/pip" install -q mujoco==3.3.7 "gymnasium>=1.1" numpy scipy imageio packaging
"$MW/bin/pip" install -q --no-deps metaworld==3.1.1
"$MW/bin/python" -c 'import metaworld, mujoco; print("metaworld ok, mujoco", mujoco.__version__)'
[ "$only_metaworld" = 0 ] || exit 0
VENV=.deps/bench-venv
venv "$VENV"
"$VENV/bin/pip" install -q torch numpy
"$VENV/bin/python" -c 'import torch; print("torch", torch.__version__, "cpu", torch.backends.cpu.get_cpu_capability())'
