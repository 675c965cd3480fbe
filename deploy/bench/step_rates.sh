#!/usr/bin/env bash
# Env steps/s of the same loop (one environment, random actions, reset at 500 steps) in terl,
# Python Meta-World 3.1.1 and EnvPool 1.2.5's native C++ Meta-World (1 environment per call,
# and 32 per call on its one worker thread: its best per-core rate here; 8 per call is about
# 10 % slower, 64 no faster), alternated round by round so that every implementation sees the
# same background load; then a table of the medians over rounds (summarize_step_rates.py).
#   deploy/bench/step_rates.sh [--rounds N] [--seconds S] [--tasks LIST] [--out DIR]
# Needs `deploy/bench/setup.sh --metaworld` and `deploy/bench/setup.sh --envpool` once, and the
# release build (cargo build --release -p terl-cli). Writes DIR/<implementation>-round<k>.json,
# DIR/env-step-rates.json and prints the table (default DIR: docs/results/scaling).
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=2 seconds=2 tasks=mt10 out=docs/results/scaling
need_value() { [ $# -ge 2 ] || { echo "$1 needs a value (see --help)" >&2; exit 2; }; }
while [ $# -gt 0 ]; do
    case "$1" in
        --rounds) need_value "$@"; rounds=$2; shift 2 ;;
        --seconds) need_value "$@"; seconds=$2; shift 2 ;;
        --tasks) need_value "$@"; tasks=$2; shift 2 ;;
        --out) need_value "$@"; out=$2; shift 2 ;;
        -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
[[ "$rounds" =~ ^[1-9][0-9]?$ ]] || { echo "--rounds must be 1..99" >&2; exit 2; }
python3 -c 'import math, sys; s = float(sys.argv[1]); sys.exit(not (math.isfinite(s) and 0.1 <= s <= 60))' "$seconds" 2>/dev/null \
    || { echo "--seconds must be a number of seconds from 0.1 to 60" >&2; exit 2; }
MT10=reach-v3,push-v3,pick-place-v3,door-open-v3,drawer-open-v3,drawer-close-v3,button-press-topdown-v3,peg-insert-side-v3,window-open-v3,window-close-v3
# The Python references take task names: mt10 or a comma-separated list of Meta-World v3 names.
case "$tasks" in
    mt10) tasks=$MT10 ;;
    *) [[ "$tasks" =~ ^[a-z-]+-v3(,[a-z-]+-v3)*$ ]] \
           || { echo "--tasks must be mt10 or comma-separated task names such as reach-v3,push-v3" >&2; exit 2; } ;;
esac
MW=.deps/metaworld-venv/bin/python EP=.deps/envpool-venv/bin/python TERL=target/release/terl
for bin in "$MW" "$EP" "$TERL"; do
    [ -x "$bin" ] || { echo "missing $bin: run deploy/bench/setup.sh and cargo build --release -p terl-cli" >&2; exit 1; }
done
mkdir -p "$out"
# Every report is written to a scratch folder first: a failed run leaves $out as it was.
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
for k in $(seq 1 "$rounds"); do
    echo "round $k/$rounds" >&2
    "$TERL" bench env --tasks "$tasks" --seconds "$seconds" --json > "$tmp/terl-bench-env-round$k.json"
    "$MW" deploy/bench/metaworld_python.py --tasks "$tasks" --seconds "$seconds" > "$tmp/python-metaworld-round$k.json"
    "$EP" deploy/bench/envpool_metaworld.py --tasks "$tasks" --seconds "$seconds" --envs 1 > "$tmp/envpool-1-round$k.json"
    "$EP" deploy/bench/envpool_metaworld.py --tasks "$tasks" --seconds "$seconds" --envs 32 > "$tmp/envpool-32-round$k.json"
done
python3 deploy/bench/summarize_step_rates.py "$tmp" "$rounds" "$seconds"
mv "$tmp"/*.json "$out"/
