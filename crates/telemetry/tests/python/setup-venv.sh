#!/usr/bin/env bash
# Creates the Python venv that the terl-telemetry interop test uses as an MCAP reader we did not
# write: the official `mcap` reader with `mcap-protobuf-support` decodes our TEP dataset files with
# the protobuf schema embedded in them.
#
# Idempotent: does nothing when the venv already has the pinned packages. Location:
# $TERL_MCAP_VENV, or .deps/mcap-venv at the repository root (git-ignored).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)"
VENV="${TERL_MCAP_VENV:-$ROOT/.deps/mcap-venv}"
MCAP_VERSION=1.6.0
MCAP_PROTOBUF_VERSION=0.6.0
PACKAGES=("mcap==$MCAP_VERSION" "mcap-protobuf-support==$MCAP_PROTOBUF_VERSION")
CHECK="import importlib.metadata as m, mcap.reader, mcap_protobuf.decoder
assert m.version('mcap') == '$MCAP_VERSION', m.version('mcap')
assert m.version('mcap-protobuf-support') == '$MCAP_PROTOBUF_VERSION'"

if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "$CHECK" 2>/dev/null; then
    echo "mcap-venv: ready at $VENV"
    exit 0
fi
echo "mcap-venv: creating $VENV"
python3 -m venv "$VENV" || {
    echo "mcap-venv: python3 -m venv failed; install python3-venv (apt-get install python3-venv)" >&2
    exit 1
}
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet "${PACKAGES[@]}"
"$VENV/bin/python" -c "$CHECK"
echo "mcap-venv: ready at $VENV"
