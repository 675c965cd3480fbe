#!/usr/bin/env bash
# Runs the Rust TEP update benchmark and the PyTorch reference alternately (F and AN 3x512,
# obs 39, act 4, batch 1024; 1 and 2 threads) and prints a side-by-side table with the
# Rust/PyTorch ratio. Alternating keeps both exposed to the same background load.
#   deploy/bench/compare_tep.sh [seconds] [rounds] [batch]
# The raw JSON lines are kept in ${TEP_RUNS:-target/tep_runs.jsonl}.
# PYTHON defaults to .deps/bench-venv/bin/python (a venv with torch; deploy/bench/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_PER_RUN=${1:-5}
ROUNDS=${2:-2}
BATCH=${3:-1024}
PYTHON=${PYTHON:-.deps/bench-venv/bin/python}
RUNS=${TEP_RUNS:-target/tep_runs.jsonl}
TARGET=${CARGO_TARGET_DIR:-target}
# A busy-waiting OpenMP pool collapses when other processes share the cores; passive waiting
# is what PyTorch should get on a shared machine (see compare_sac.sh).
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
if ! "$PYTHON" -c 'import torch' 2>/dev/null; then
  echo "$(basename "$0"): no PyTorch at PYTHON=$PYTHON; run deploy/bench/setup.sh first (or set PYTHON to a Python with torch)" >&2
  exit 1
fi
cargo build --release -q -p terl-bench --example tep_bench
mkdir -p "$(dirname "$RUNS")"
: >"$RUNS"
for round in $(seq "$ROUNDS"); do
  for threads in 1 2; do
    args=(--batch "$BATCH" --threads "$threads" --seconds "$SECONDS_PER_RUN")
    "$TARGET/release/examples/tep_bench" "${args[@]}" | tee -a "$RUNS"
    CUDA_VISIBLE_DEVICES= "$PYTHON" deploy/bench/tep_torch.py "${args[@]}" | tee -a "$RUNS"
  done
done
echo
"$PYTHON" deploy/bench/summarize_tep.py <"$RUNS"
