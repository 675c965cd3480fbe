#!/usr/bin/env bash
# Creates the Python venv that the terl-wire interop test uses as a gRPC client we did not write:
# grpcio-reflection (v1 and v1alpha) and grpcio-health-checking talk to our tonic servers.
#
# Idempotent: does nothing when the venv already has the packages. Location: $TERL_GRPC_VENV, or
# .deps/grpc-venv at the repository root (git-ignored).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../../.." && pwd)"
VENV="${TERL_GRPC_VENV:-$ROOT/.deps/grpc-venv}"
PACKAGES=(grpcio grpcio-reflection grpcio-health-checking protobuf)

if [ -x "$VENV/bin/python" ] &&
    "$VENV/bin/python" -c "import grpc, grpc_reflection, grpc_health, google.protobuf" 2>/dev/null; then
    echo "grpc-venv: ready at $VENV"
    exit 0
fi
echo "grpc-venv: creating $VENV"
python3 -m venv "$VENV" || {
    echo "grpc-venv: python3 -m venv failed; install python3-venv (apt-get install python3-venv)" >&2
    exit 1
}
"$VENV/bin/python" -m pip install --quiet --upgrade pip
"$VENV/bin/python" -m pip install --quiet "${PACKAGES[@]}"
"$VENV/bin/python" -c "import grpc, grpc_reflection, grpc_health, google.protobuf"
echo "grpc-venv: ready at $VENV"
