#!/usr/bin/env bash
# The main job: a local training cluster — one learner, one selector and N actors — on this machine.
#
#   ./deploy/local-cluster.sh [--config FILE] [--actors N] [--run-id ID] [--tep-dataset MCAP]...
#                             [--learner-addr ADDR] [--selector-addr ADDR] [--runs-root DIR]
#                             [--no-build]
#
# --config       run file (default deploy/configs/mt10.toml; quick checks: deploy/configs/cluster-smoke.toml,
#                and deploy/configs/smoke-terl.toml for the whole TERL loop within two minutes)
# --tep-dataset  algorithm = "terl": start the planner's buffer from an earlier run's runs/<id>/tep-dataset.mcap
#                (repeat the option to load several, e.g. the five MT1-Ind datasets)
# --runs-root    folder of run folders (default runs; `terl cluster down` looks in runs/)
# --actors       actor processes (default: cores - 1, at least 1)
# --learner-addr / --selector-addr   gRPC addresses (default 127.0.0.1:50051 / 127.0.0.1:50052;
#                port 0 picks a free port, written to runs/<id>/<service>.addr)
# Logs, the resolved config and checkpoints go to runs/<id>/; progress (terl status) prints every
# few seconds. Ctrl-C (or `terl cluster down`) stops every process and waits for them. With
# algorithm = "terl" the selected samples also go to runs/<id>/tep-dataset.mcap.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

config=deploy/configs/mt10.toml
cores=$(nproc 2>/dev/null || echo 2)
actors=$(( cores > 1 ? cores - 1 : 1 ))
run_id=""
learner_addr=127.0.0.1:50051
selector_addr=127.0.0.1:50052
build=1
tep_datasets=()
runs_root=runs
while [ $# -gt 0 ]; do
    case "$1" in
        --config) config=$2; shift 2 ;;
        --actors) actors=$2; shift 2 ;;
        --run-id) run_id=$2; shift 2 ;;
        --learner-addr) learner_addr=$2; shift 2 ;;
        --selector-addr) selector_addr=$2; shift 2 ;;
        --no-build) build=0; shift ;;
        --runs-root) runs_root=$2; shift 2 ;;
        --tep-dataset) tep_datasets+=("$2"); shift 2 ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
[ -f "$config" ] || { echo "config not found: $config" >&2; exit 2; }
for d in "${tep_datasets[@]}"; do
    [ -f "$d" ] || { echo "TEP dataset not found: $d" >&2; exit 2; }
done
[[ "$actors" =~ ^[1-9][0-9]*$ ]] || { echo "--actors must be a positive integer" >&2; exit 2; }

if [ "$build" = 1 ]; then
    ./deploy/setup.sh
    echo "[cluster] building release binaries (first time: a few minutes)" >&2
    cargo build --release -q -p terl-cli -p terl-learner -p terl-actor -p terl-selector
fi
bin=${CARGO_TARGET_DIR:-target}/release

run_id=${run_id:-"$(basename "$config" .toml)-$(date +%Y%m%d-%H%M%S)"}
# Shared-memory service names carry the run id machine-wide: a second cluster with the id of a
# live one (even in another runs root, or orphans of a killed launcher) would mix with it.
if live=$(pgrep -f -- "terl-(learner|selector|actor) .*--run-id $run_id( |\$)"); then
    echo "run id $run_id is in use by running processes ($(echo $live | tr '\n' ' ')): stop them, or choose another --run-id" >&2
    exit 2
fi
out="$runs_root/$run_id"
mkdir -p "$out"
cp "$config" "$out/config.toml"
cat > "$out/cluster.txt" <<INFO
run_id=$run_id
config=$config
actors=$actors
learner_addr=$learner_addr
selector_addr=$selector_addr
started=$(date -Iseconds)
INFO
echo $$ > "$runs_root/.cluster.pid"

pids=()
stopping=0
stop() {
    [ "$stopping" = 1 ] && return
    stopping=1
    echo "[cluster] stopping ${#pids[@]} processes" >&2
    for p in "${pids[@]}"; do kill -TERM "$p" 2>/dev/null || true; done
    stop_code=0
    for p in "${pids[@]}"; do
        code=0
        wait "$p" || code=$?
        # A signal reaching this script interrupts `wait` (status > 128) before the child exits.
        while [ "$code" -gt 128 ] && kill -0 "$p" 2>/dev/null; do
            code=0
            wait "$p" || code=$?
        done
        [ "$code" -gt "$stop_code" ] && stop_code=$code
    done
    rm -f "$runs_root/.cluster.pid"
    echo "[cluster] stopped (worst exit code ${stop_code}; run folder $out)" >&2
}
# The traps only record the signal; the main loop notices it and stops the cluster outside the
# handler (exiting from inside a trap during `wait` trips a bash bug).
interrupted=""
trap 'interrupted=130' INT
trap 'interrupted=143' TERM

common=(--config "$out/config.toml" --run-id "$run_id" --num-actors "$actors")
rm -f "$out/learner.addr" "$out/selector.addr"
wait_addr() {
    for _ in $(seq 300); do [ -s "$out/$1.addr" ] && return 0; sleep 0.1; done
    echo "[cluster] $1 did not start; see $out/$1.log" >&2; tail -5 "$out/$1.log" >&2; stop; exit 1
}
learner_extra=()
for d in "${tep_datasets[@]}"; do learner_extra+=(--tep-dataset "$d"); done
"$bin/terl-learner" "${common[@]}" --addr "$learner_addr" --run-dir "$out" "${learner_extra[@]}" 2> "$out/learner.log" &
pids+=($!)
wait_addr learner
learner_addr=$(cat "$out/learner.addr")
# The selector follows the learner's weights (PTR scoring with algorithm = "terl").
"$bin/terl-selector" "${common[@]}" --addr "$selector_addr" --run-dir "$out" --learner-addr "$learner_addr" 2> "$out/selector.log" &
pids+=($!)
wait_addr selector
selector_addr=$(cat "$out/selector.addr")
for ((i = 0; i < actors; i++)); do
    "$bin/terl-actor" "${common[@]}" --actor-id "$i" --learner-addr "$learner_addr" 2> "$out/actor-$i.log" &
    pids+=($!)
done
echo "[cluster] run $run_id: learner $learner_addr, selector $selector_addr, $actors actor(s); logs in $out/. Ctrl-C stops." >&2

while [ -z "$interrupted" ]; do
    sleep 5 &
    wait $! || true
    [ -n "$interrupted" ] && break
    for p in "${pids[@]}"; do
        if ! kill -0 "$p" 2>/dev/null; then
            code=0
            wait "$p" || code=$?
            learner_pid=${pids[0]}
            rest=()
            for q in "${pids[@]}"; do [ "$q" = "$p" ] || rest+=("$q"); done
            pids=("${rest[@]}")
            if [ "$p" = "$learner_pid" ] && [ "$code" = 0 ]; then
                echo "[cluster] the learner finished (train.total_env_steps reached); stopping the cluster" >&2
                stop || true
                exit 0
            fi
            echo "[cluster] process $p exited with code $code; stopping the cluster (logs in $out/)" >&2
            stop || true
            exit 1
        fi
    done
    echo "---- $(date +%H:%M:%S)" >&2
    "$bin/terl" status --addr "$learner_addr" --selector-addr "$selector_addr" >&2 || true
done
stop
exit "$interrupted"
