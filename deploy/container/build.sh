#!/usr/bin/env bash
# Builds the terl container image with podman (deploy/container/Dockerfile).
#
#   deploy/container/build.sh [--staged | --full] [--tag IMAGE] [--base IMAGE] [--bin-dir DIR]
#
#   --staged         (default) the runtime image from the binaries already built on this host
#                    (cargo build --release, or --bin-dir DIR): stage.sh copies them with
#                    libmujoco, the Meta-World assets and the run files into a folder, and the
#                    Dockerfile's `runtime-staged` target puts that folder at /opt/terl. A few
#                    seconds; the binaries must be built for a glibc no newer than bookworm's.
#   --full           the whole multi-stage build from the repository root (the `build` stage
#                    compiles inside rust:1.95-bookworm, which must be pullable from a registry).
#   --tag IMAGE      the image's name (default localhost/terl:latest).
#   --base IMAGE     the runtime's base. Default: localhost/terl-base:bookworm, made from Debian
#                    packages by base-image.sh when it does not exist (no registry needed); pass
#                    debian:bookworm-slim where a registry is reachable.
#
# Needs ./deploy/setup.sh --container (podman, runc, debootstrap) and root for the base image.
# Prints the image's size when done.
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
root=$(cd "$here/../.." && pwd)
mode=staged
tag=localhost/terl:latest
base=
bin_dir=
while [ $# -gt 0 ]; do
    case "$1" in
        --staged) mode=staged; shift ;;
        --full) mode=full; shift ;;
        --tag) tag=${2:?--tag needs an image name}; shift 2 ;;
        --base) base=${2:?--base needs an image name}; shift 2 ;;
        --bin-dir) bin_dir=${2:?--bin-dir needs a folder}; shift 2 ;;
        *) sed -n '2,/^set -euo/{/^set -euo/!p}' "$0" >&2; exit 2 ;;
    esac
done
podman() { "$here/podman.sh" "$@"; }
if [ -z "$base" ]; then
    base=localhost/terl-base:bookworm
    "$here/base-image.sh" --tag "$base"
fi
start=$(date +%s)
case "$mode" in
    staged)
        ctx=$(mktemp -d "${TMPDIR:-/tmp}/terl-stage.XXXXXX")
        trap 'rm -rf "$ctx"' EXIT
        "$here/stage.sh" ${bin_dir:+--bin-dir "$bin_dir"} "$ctx/opt-terl"
        podman build --quiet --target runtime-staged --build-arg "BASE_IMAGE=$base" \
            -f "$here/Dockerfile" -t "$tag" "$ctx/opt-terl" >/dev/null
        ;;
    full)
        podman build --build-arg "BASE_IMAGE=$base" -f "$here/Dockerfile" -t "$tag" "$root"
        ;;
esac
size=$(podman image inspect --format '{{.Size}}' "$tag")
echo "image $tag ($mode): $(awk -v s="$size" 'BEGIN {printf "%.0f MB", s / 1e6}') in $(( $(date +%s) - start )) s" >&2
