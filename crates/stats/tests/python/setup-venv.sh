#!/usr/bin/env bash
# Creates the Python venv that the terl-stats test (tests/rliable.rs) uses as its second path:
# the rliable library of Agarwal et al. (2021), whose IQM, mean, probability of improvement and
# stratified bootstrap intervals the crate must reproduce.
#
# Versions are pinned: rliable 1.2.0 imports arch, and arch 7.2.0 does not import under pandas 3.
# Idempotent: does nothing when the venv already has the pinned packages. Location:
# .deps/rliable-venv at the repository root (git-ignored).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)"
VENV="$ROOT/.deps/rliable-venv"
PACKAGES=("rliable==1.2.0" "arch==7.2.0" "pandas==2.3.3" "numpy==2.4.6" "scipy==1.17.1")
CHECK="import importlib.metadata as m
from rliable import library, metrics
assert m.version('rliable') == '1.2.0', m.version('rliable')
assert m.version('arch') == '7.2.0', m.version('arch')"

if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "$CHECK" 2>/dev/null; then
    echo "rliable-venv: ready at $VENV"
    exit 0
fi
echo "rliable-venv: creating $VENV"
python3 -m venv "$VENV" || {
    echo "rliable-venv: python3 -m venv failed; install python3-venv (apt-get install python3-venv)" >&2
    exit 1
}
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet "${PACKAGES[@]}"
"$VENV/bin/python" -c "$CHECK"
echo "rliable-venv: ready at $VENV"
