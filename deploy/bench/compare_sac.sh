#!/usr/bin/env bash
# Runs the Rust SAC benchmark and the PyTorch reference alternately on the issue's configs
# (obs 49, act 4: 3x400 batch 1280, 3x400 batch 256, 2x256 batch 256; 1 and 2 threads) and
# prints a side-by-side table with the per-round Rust/PyTorch ratios and the floors.
# Alternating keeps both exposed to the same background load.
#   deploy/bench/compare_sac.sh [seconds] [rounds] [threads...]
# The raw JSON lines are kept in ${SAC_RUNS:-target/sac_runs.jsonl}.
# PYTHON defaults to .deps/bench-venv/bin/python (a venv with torch; deploy/bench/setup.sh).
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_PER_RUN=${1:-4}
ROUNDS=${2:-2}
shift $(($# < 2 ? $# : 2))
[ $# -gt 0 ] && THREADS=("$@") || THREADS=(1 2)
PYTHON=${PYTHON:-.deps/bench-venv/bin/python}
RUNS=${SAC_RUNS:-target/sac_runs.jsonl}
TARGET=${CARGO_TARGET_DIR:-target}
# A busy-waiting OpenMP pool collapses when other processes share the cores; passive waiting
# is what PyTorch should get on a shared machine (measured: 3.3 vs 19.3 updates/s, 2x256 b256).
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
if ! "$PYTHON" -c 'import torch' 2>/dev/null; then
  echo "$(basename "$0"): no PyTorch at PYTHON=$PYTHON; run deploy/bench/setup.sh first (or set PYTHON to a Python with torch)" >&2
  exit 1
fi
cargo build --release -q -p terl-bench --example sac_bench
mkdir -p "$(dirname "$RUNS")"
: >"$RUNS"
for round in $(seq "$ROUNDS"); do
  for cfg in "3 400 1280" "3 400 256" "2 256 256"; do
    read -r layers hidden batch <<<"$cfg"
    for threads in "${THREADS[@]}"; do
      args=(--layers "$layers" --hidden "$hidden" --batch "$batch" --threads "$threads" --seconds "$SECONDS_PER_RUN")
      "$TARGET/release/examples/sac_bench" "${args[@]}" | tee -a "$RUNS"
      CUDA_VISIBLE_DEVICES= "$PYTHON" deploy/bench/sac_torch.py "${args[@]}" | tee -a "$RUNS"
    done
  done
done
echo
"$PYTHON" deploy/bench/summarize_sac.py <"$RUNS"
