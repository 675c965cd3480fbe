#!/usr/bin/env bash
# Creates the Python venv with the Kubernetes schema validator that ./deploy/test.sh runs on
# deploy/k8s/*.yaml (kubernetes-validate: the API's OpenAPI schemas, bundled, checked offline).
#
# Idempotent: does nothing when the venv already has the pinned version. Location:
# $TERL_K8S_VENV, or .deps/k8s-venv at the repository root (git-ignored).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
VENV="${TERL_K8S_VENV:-$ROOT/.deps/k8s-venv}"
VERSION=1.37.0
CHECK="import importlib.metadata as m; assert m.version('kubernetes-validate') == '$VERSION'"

if [ -x "$VENV/bin/kubernetes-validate" ] && "$VENV/bin/python" -c "$CHECK" 2>/dev/null; then
    echo "k8s-venv: ready at $VENV"
    exit 0
fi
echo "k8s-venv: creating $VENV"
python3 -m venv "$VENV" || {
    echo "k8s-venv: python3 -m venv failed; install python3-venv (apt-get install python3-venv)" >&2
    exit 1
}
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet "kubernetes-validate==$VERSION"
"$VENV/bin/python" -c "$CHECK"
echo "k8s-venv: ready at $VENV"
