#!/usr/bin/env bash
# Runs the Rust SAC benchmark and the PyTorch reference alternately on the issue's configs
# (obs 49, act 4: 3x400 batch 1280, 3x400 batch 256, 2x256 batch 256; 1 and 2 threads) and
# prints one JSON line per run. Alternating keeps both exposed to the same background load.
#   deploy/bench/compare_sac.sh [seconds] [rounds] > runs.jsonl
# PYTHON defaults to .deps/bench-venv/bin/python (a venv with torch).
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_PER_RUN=${1:-4}
ROUNDS=${2:-2}
PYTHON=${PYTHON:-.deps/bench-venv/bin/python}
# A busy-waiting OpenMP pool collapses when other processes share the cores; passive waiting
# is what PyTorch should get on a shared machine (measured: 3.3 vs 19.3 updates/s, 2x256 b256).
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
cargo build --release -q -p terl-bench --example sac_bench
BIN=${CARGO_TARGET_DIR:-target}/release/examples/sac_bench
for round in $(seq "$ROUNDS"); do
  for cfg in "3 400 1280" "3 400 256" "2 256 256"; do
    set -- $cfg
    for threads in 1 2; do
      args=(--layers "$1" --hidden "$2" --batch "$3" --threads "$threads" --seconds "$SECONDS_PER_RUN")
      "$BIN" "${args[@]}"
      CUDA_VISIBLE_DEVICES= "$PYTHON" deploy/bench/sac_torch.py "${args[@]}"
    done
  done
done
