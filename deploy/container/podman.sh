#!/usr/bin/env bash
# podman with terl's settings (deploy/container/containers.conf): use it exactly like podman.
#
#   deploy/container/podman.sh run --rm localhost/terl:latest terl env list
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
command -v podman >/dev/null || {
    echo "podman not found: run ./deploy/setup.sh --container (installs podman, runc, debootstrap)" >&2
    exit 1
}
CONTAINERS_CONF=${CONTAINERS_CONF:-$here/containers.conf} exec podman "$@"
