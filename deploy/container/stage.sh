#!/usr/bin/env bash
# Copies what the services need at run time into one relocatable folder DEST: the release
# binaries (bin/), libmujoco 3.3.7 from the MuJoCo wheel (lib/), the Meta-World assets from the
# Meta-World wheel (assets/metaworld), the run files (configs/) and env.sh, which points the
# binaries at lib/ and assets/ (TERL_MUJOCO_LIB, TERL_METAWORLD_ASSETS) wherever DEST ends up.
# The container image's runtime stage is this folder (deploy/container/Dockerfile); the test
# services/cli/tests/container.rs runs the staged binaries from it.
#
#   deploy/container/stage.sh [--bin-dir DIR] DEST
#
# after ./deploy/setup.sh and cargo build --release (DIR defaults to target/release).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
bin=${CARGO_TARGET_DIR:-$ROOT/target}/release
if [ "${1:-}" = "--bin-dir" ]; then
    [ $# -ge 2 ] || { echo "--bin-dir needs a folder" >&2; exit 2; }
    bin=$2
    shift 2
fi
[ $# -eq 1 ] || { echo "usage: $0 [--bin-dir DIR] DEST" >&2; exit 2; }
dest=$1
lib=$ROOT/.deps/mujoco/lib/libmujoco.so.3.3.7
assets=$ROOT/assets/metaworld
for f in "$bin/terl" "$bin/terl-learner" "$bin/terl-selector" "$bin/terl-actor"; do
    [ -x "$f" ] || { echo "missing $f: run cargo build --release first" >&2; exit 1; }
done
[ -f "$lib" ] && [ -d "$assets" ] || { echo "missing libmujoco or assets: run ./deploy/setup.sh first" >&2; exit 1; }
mkdir -p "$dest/bin" "$dest/lib" "$dest/assets" "$dest/configs"
cp "$bin/terl" "$bin/terl-learner" "$bin/terl-selector" "$bin/terl-actor" "$dest/bin/"
cp "$lib" "$dest/lib/"
ln -sf libmujoco.so.3.3.7 "$dest/lib/libmujoco.so"
rm -rf "$dest/assets/metaworld"
cp -r "$assets" "$dest/assets/metaworld"
cp "$ROOT"/deploy/configs/*.toml "$dest/configs/"
cat > "$dest/env.sh" <<'ENV'
# Source this file to run the staged binaries from wherever this folder is.
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
export PATH="$here/bin:$PATH"
export TERL_MUJOCO_LIB="$here/lib/libmujoco.so"
export TERL_METAWORLD_ASSETS="$here/assets/metaworld"
ENV
echo "staged terl into $dest ($(du -sh "$dest" | cut -f1))" >&2
