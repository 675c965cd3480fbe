#!/usr/bin/env bash
# Creates the Python environments of the benchmarks' references. Not part of deploy/setup.sh:
# the tests do not need them, and the PyTorch wheel is a large download.
#   deploy/bench/setup.sh              all three
#   deploy/bench/setup.sh --metaworld  only .deps/metaworld-venv
#   deploy/bench/setup.sh --envpool    only .deps/envpool-venv
# - .deps/bench-venv: PyTorch (CPU is enough), for compare_sac.sh and compare_tep.sh;
# - .deps/metaworld-venv: Python Meta-World 3.1.1 on MuJoCo 3.3.7 (metaworld 3.1.1 asks for
#   mujoco 3.3.0; its code runs on the 3.3.7 this project pins), for metaworld_python.py;
# - .deps/envpool-venv: EnvPool 1.2.5, whose native C++ Meta-World v3 (`MetaWorld/<Task>-v3`,
#   its own MuJoCo) is the fastest other implementation, for envpool_metaworld.py. Its wheels
#   need Python 3.11 or newer on x86-64 or aarch64 Linux.
set -euo pipefail
cd "$(dirname "$0")/../.."
only=""
while [ $# -gt 0 ]; do
    case "$1" in
        --metaworld|--envpool)
            [ -z "$only" ] || { echo "give one of --metaworld and --envpool (or neither: all three)" >&2; exit 2; }
            only=${1#--}; shift ;;
        -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
venv() {
    [ -x "$1/bin/python" ] || python3 -m venv "$1"
    "$1/bin/pip" install -q --upgrade pip
}
envpool() {
    python3 -c 'import sys; sys.exit(sys.version_info < (3, 11))' || {
        echo "EnvPool 1.2.5 needs Python 3.11 or newer; python3 is $(python3 --version 2>&1)" >&2
        return 1
    }
    local EP=.deps/envpool-venv
    venv "$EP"
    "$EP/bin/pip" install -q envpool==1.2.5 numpy
    "$EP/bin/python" -c 'import envpool; envpool.make("MetaWorld/Reach-v3", env_type="gymnasium", num_envs=1); print("envpool", envpool.__version__, "Meta-World ok")'
}
if [ "$only" = envpool ]; then envpool; exit; fi
MW=.deps/metaworld-venv
venv "$MW"
"$MW/bin/pip" install -q mujoco==3.3.7 "gymnasium>=1.1" numpy scipy imageio packaging
"$MW/bin/pip" install -q --no-deps metaworld==3.1.1
"$MW/bin/python" -c 'import metaworld, mujoco; print("metaworld ok, mujoco", mujoco.__version__)'
[ "$only" != metaworld ] || exit 0
VENV=.deps/bench-venv
venv "$VENV"
"$VENV/bin/pip" install -q torch numpy
"$VENV/bin/python" -c 'import torch; print("torch", torch.__version__, "cpu", torch.backends.cpu.get_cpu_capability())'
# Last, and not fatal here: EnvPool's wheels need Python 3.11 (step_rates.sh says what is missing).
envpool || echo "EnvPool skipped: the other two venvs are ready" >&2
