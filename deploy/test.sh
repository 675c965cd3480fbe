#!/usr/bin/env bash
# Runs every check a change must pass: formatting, clippy, rustdoc, and the whole test suite (unit,
# parity with Python Meta-World, learning tests, integration) in release mode, then a
# 2-minute soak of the smoke cluster under injected faults (deploy/soak.sh).
#
#   ./deploy/test.sh            everything
#   ./deploy/test.sh -E 'binary(parity)'   only the parity tests (any nextest filter; no soak)
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

# --container: podman, runc and debootstrap for the container image test (services/cli/tests/container.rs).
"$ROOT/deploy/setup.sh" --container

say() { printf '\n[test] %s\n' "$*" >&2; }
start=$(date +%s)

say "cargo fmt --check"
cargo fmt --all -- --check

say "cargo clippy (all targets, warnings are errors)"
cargo clippy --workspace --all-targets --release -- -D warnings

say "rustdoc (warnings are errors: broken links, and missing docs where a crate asks for them)"
RUSTDOCFLAGS="-D warnings" cargo doc --workspace --no-deps --release -q

say "Kubernetes manifests (deploy/k8s) against the API's schemas"
"$ROOT/.deps/k8s-venv/bin/kubernetes-validate" --strict --quiet "$ROOT"/deploy/k8s/*.yaml

say "the service binaries the cluster tests start (built here once, not inside a test)"
# The same packages services/cli/tests/common::service_binaries builds: the test build below
# compiles them with the dev-dependencies' features, a separate set that coexists with this one.
cargo build --release -q -p terl-cli -p terl-learner -p terl-actor -p terl-selector

say "tests (release)"
if cargo nextest --version >/dev/null 2>&1; then
    cargo nextest run --workspace --release --no-fail-fast "$@"
else
    cargo test --workspace --release --no-fail-fast -- "$@"
fi

if [ $# -eq 0 ]; then
    say "soak: the smoke cluster for 2 minutes, an actor killed every 30 s and the learner once"
    ./deploy/soak.sh --minutes 2 --kill-every 30 --no-build
fi

say "all checks passed in $(( $(date +%s) - start )) s"
