#!/usr/bin/env bash
# A Debian bookworm base image built from Debian packages, for machines that reach the Debian
# package mirror but no container registry (so `FROM debian:bookworm-slim` cannot be pulled):
# debootstrap's minbase variant plus what the terl runtime needs (ca-certificates,
# fonts-dejavu-core), documentation and package lists removed, imported into podman.
#
#   deploy/container/base-image.sh [--tag IMAGE] [--mirror URL] [--rebuild]
#
# IMAGE defaults to localhost/terl-base:bookworm; an existing image is kept unless --rebuild.
# The mirror defaults to the host's own Debian mirror (the first URIs of its apt sources).
# Needs root (debootstrap), podman and debootstrap (./deploy/setup.sh --container).
set -euo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
tag=localhost/terl-base:bookworm
mirror=
rebuild=0
while [ $# -gt 0 ]; do
    case "$1" in
        --tag) tag=${2:?--tag needs an image name}; shift 2 ;;
        --mirror) mirror=${2:?--mirror needs a URL}; shift 2 ;;
        --rebuild) rebuild=1; shift ;;
        *) echo "usage: $0 [--tag IMAGE] [--mirror URL] [--rebuild]" >&2; exit 2 ;;
    esac
done
podman() { "$here/podman.sh" "$@"; }
if [ "$rebuild" = 0 ] && podman image exists "$tag"; then
    echo "base image $tag exists (--rebuild to make it again)" >&2
    exit 0
fi
command -v debootstrap >/dev/null || {
    echo "debootstrap not found: run ./deploy/setup.sh --container" >&2
    exit 1
}
[ "$(id -u)" -eq 0 ] || { echo "debootstrap needs root" >&2; exit 1; }
if [ -z "$mirror" ]; then
    # The host's Debian mirror: deb822 sources first, then the one-line format.
    mirror=$(awk '/^URIs:/ {print $2; exit}' /etc/apt/sources.list.d/*.sources 2>/dev/null || true)
    [ -n "$mirror" ] || mirror=$(awk '$1 == "deb" {for (i = 2; i <= NF; i++) if ($i ~ /:\/\//) {print $i; exit}}' \
        /etc/apt/sources.list 2>/dev/null || true)
    [ -n "$mirror" ] || { echo "no Debian mirror in the host's apt sources: pass --mirror URL" >&2; exit 1; }
fi
root=$(mktemp -d "${TMPDIR:-/tmp}/terl-rootfs.XXXXXX")
trap 'rm -rf "$root"' EXIT
start=$(date +%s)
echo "debootstrap bookworm (minbase) from the host's mirror into $root" >&2
debootstrap --variant=minbase --include=ca-certificates,fonts-dejavu-core bookworm "$root" "$mirror" \
    >"$root.log" 2>&1 || { tail -20 "$root.log" >&2; rm -f "$root.log"; exit 1; }
rm -f "$root.log"
rm -rf "$root"/usr/share/doc/* "$root"/usr/share/man/* "$root"/usr/share/info/* \
    "$root"/var/cache/apt/*.bin "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/*
tar --numeric-owner -C "$root" -c . | podman import --quiet - "$tag" >/dev/null
echo "base image $tag: $(podman image inspect --format '{{.Size}}' "$tag" | awk '{printf "%.0f MB", $1/1e6}') in $(( $(date +%s) - start )) s" >&2
