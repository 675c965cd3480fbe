#!/usr/bin/env bash
# The main job: a local training cluster — one learner, one selector and N actors — on this machine.
#
#   ./deploy/local-cluster.sh [--config FILE] [--actors N] [--run-id ID] [--tep-dataset MCAP]...
#                             [--learner-addr ADDR] [--selector-addr ADDR] [--runs-root DIR]
#                             [--restarts N] [--restart-backoff SECS] [--no-build]
#   ./deploy/local-cluster.sh --resume runs/<id> [--actors N] [--learner-addr ADDR] [--selector-addr ADDR]
#                             [--restarts N] [--no-build]
#
# --config       run file (default deploy/configs/mt10.toml; quick checks: deploy/configs/cluster-smoke.toml,
#                and deploy/configs/smoke-terl.toml for the whole TERL loop within two minutes)
# --resume DIR   continue the run in DIR after any stop (Ctrl-C, a crash, kill -9): its config.toml,
#                run id, TEP datasets, actor count and addresses; the learner continues from its newest intact checkpoint,
#                the selector rebuilds its success windows and PTR gates from the episode logs, and
#                new logs go to new files next to the old ones (terl report joins them)
# --tep-dataset  algorithm = "terl": start the planner's buffer from an earlier run's runs/<id>/tep-dataset.mcap
#                (repeat the option to load several, e.g. the five MT1-Ind datasets)
# --runs-root    folder of run folders (default runs; `terl cluster down` looks in runs/)
# --actors       actor processes (default: cores - 1, at least 1)
# --learner-addr / --selector-addr   gRPC addresses (default 127.0.0.1:0: a free port, written to
#                runs/<id>/<service>.addr; `terl status` finds the cluster started last, or
#                `terl status --run runs/<id>` a given one)
# --restarts N   restart a process that dies (exit code other than 0, or a signal) up to N times
#                per process, the learner and selector with --resume (default 3; 0: a death stops
#                the cluster). An error exit (code 1 or 2) within 10 s of a start is a start-up
#                failure a restart would repeat: the cluster stops and prints the error instead
# --restart-backoff SECS   wait before a restart, doubled for each further restart of the same
#                process, at most 60 s (default 2)
# Logs, the resolved config and checkpoints go to runs/<id>/; progress (terl status) prints every
# few seconds. Ctrl-C (or `terl cluster down [ID]`) stops every process and waits for them; the
# services also stop by themselves if this script is killed (they follow its pid). With
# algorithm = "terl" the selected samples also go to runs/<id>/tep-dataset.mcap.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

config=deploy/configs/mt10.toml
config_given=0
addr_given=0
selector_given=0
cores=$(nproc 2>/dev/null || echo 2)
actors=""
run_id=""
learner_addr=127.0.0.1:0
selector_addr=127.0.0.1:0
build=1
tep_datasets=()
runs_root=runs
resume=""
restarts=3
backoff=2
while [ $# -gt 0 ]; do
    case "$1" in
        --config|--actors|--run-id|--learner-addr|--selector-addr|--runs-root|--tep-dataset|--resume|--restarts|--restart-backoff)
            [ $# -ge 2 ] || { echo "$1 needs a value (see --help)" >&2; exit 2; } ;;
    esac
    case "$1" in
        --config) config=$2; config_given=1; shift 2 ;;
        --actors) actors=$2; shift 2 ;;
        --run-id) run_id=$2; shift 2 ;;
        --learner-addr) learner_addr=$2; addr_given=1; shift 2 ;;
        --selector-addr) selector_addr=$2; selector_given=1; shift 2 ;;
        --no-build) build=0; shift ;;
        --runs-root) runs_root=$2; shift 2 ;;
        --tep-dataset) tep_datasets+=("$2"); shift 2 ;;
        --resume) resume=$2; shift 2 ;;
        --restarts) restarts=$2; shift 2 ;;
        --restart-backoff) backoff=$2; shift 2 ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
[[ "$restarts" =~ ^[0-9]+$ ]] || { echo "--restarts must be a non-negative integer" >&2; exit 2; }
[[ "$backoff" =~ ^[0-9]+$ ]] || { echo "--restart-backoff must be a whole number of seconds" >&2; exit 2; }
if [ -n "$resume" ]; then
    resume=${resume%/}
    [ "$config_given" = 0 ] && [ -z "$run_id" ] && [ ${#tep_datasets[@]} -eq 0 ] \
        || { echo "--resume takes the run's own config, run id and TEP datasets; drop --config/--run-id/--tep-dataset" >&2; exit 2; }
    [ -f "$resume/config.toml" ] || { echo "--resume: $resume/config.toml not found (not a run folder)" >&2; exit 2; }
    run_id=$(basename "$resume")
    runs_root=$(dirname "$resume")
    config="$resume/config.toml"
    # The TEP datasets the run started from, and its actor count and addresses unless given.
    while IFS= read -r line; do
        case "$line" in
            tep_dataset=*) tep_datasets+=("${line#tep_dataset=}") ;;
            actors=*) [ -n "$actors" ] || actors=${line#actors=} ;;
            learner_addr=*) [ "$addr_given" = 1 ] || learner_addr=${line#learner_addr=} ;;
            selector_addr=*) [ "$selector_given" = 1 ] || selector_addr=${line#selector_addr=} ;;
        esac
    done < <(grep -E '^(tep_dataset|actors|learner_addr|selector_addr)=' "$resume/cluster.txt" 2>/dev/null || true)
fi
actors=${actors:-$(( cores > 1 ? cores - 1 : 1 ))}
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
[[ "$run_id" =~ ^[A-Za-z0-9._-]{1,64}$ ]] && [ "$run_id" != . ] && [ "$run_id" != .. ] || {
    echo "--run-id must be 1 to 64 characters of A-Z a-z 0-9 . _ - (got \"$run_id\")" >&2; exit 2; }
# Shared-memory service names carry the run id machine-wide: a second cluster with the id of a
# live one (even in another runs root, or orphans of a killed launcher) would mix with it.
# A lock per run id, held by this launcher only (fd 9, closed in every long-lived child, so it
# is free the moment the launcher is gone), refuses a second launcher even when both start in
# the same instant; the process check below catches services still running (a killed
# launcher's, or ones started by hand).
lock_dir=${TMPDIR:-/tmp}/terl-run-locks
mkdir -p "$lock_dir"
exec 9>> "$lock_dir/$run_id.lock"
if ! flock -n 9; then
    echo "run id $run_id is in use by another launcher or its processes (lock $lock_dir/$run_id.lock): stop it, or choose another --run-id" >&2
    exit 2
fi
if live=$(pgrep -f -- "terl-(learner|selector|actor) .*--run-id ${run_id//./\\.}( |\$)"); then
    echo "run id $run_id is in use by running processes ($(echo $live | tr '\n' ' ')): stop them, or choose another --run-id" >&2
    exit 2
fi
out="$runs_root/$run_id"
mkdir -p "$out"
if [ -z "$resume" ]; then
    cp "$config" "$out/config.toml"
    {
        echo "run_id=$run_id"
        echo "config=$config"
        echo "actors=$actors"
        echo "learner_addr=$learner_addr"
        echo "selector_addr=$selector_addr"
        for d in "${tep_datasets[@]}"; do echo "tep_dataset=$d"; done
        echo "started=$(date -Iseconds)"
    } > "$out/cluster.txt"
else
    echo "resumed=$(date -Iseconds) actors=$actors" >> "$out/cluster.txt"
    if ! compgen -G "$out/checkpoints/*.safetensors" > /dev/null; then
        echo "[cluster] warning: $out/checkpoints holds no checkpoint: the learner starts this run again from update 0" >&2
    fi
fi
echo $$ > "$runs_root/.cluster.pid"
echo "$out" > "$runs_root/.cluster.run"
echo $$ > "$out/launcher.pid"

# Processes by role: learner, selector, actor-<i>; their pids, restarts so far and the last
# exit code of each (the summary reports the worst).
declare -A pid_of=() restarts_of=() started_at=()
# Services print errors without a backtrace (panics still follow RUST_BACKTRACE).
export RUST_LIB_BACKTRACE=0
# A process that exits with an error this soon after it started is not restarted.
min_uptime=10
worst=0
stopping=0
reason=""
stop() {
    [ "$stopping" = 1 ] && return
    stopping=1
    echo "[cluster] stopping ${#pid_of[@]} processes" >&2
    for r in "${!pid_of[@]}"; do kill -TERM "${pid_of[$r]}" 2>/dev/null || true; done
    for r in "${!pid_of[@]}"; do
        p=${pid_of[$r]}
        code=0
        wait "$p" || code=$?
        # A signal reaching this script interrupts `wait` (status > 128) before the child exits.
        while [ "$code" -gt 128 ] && kill -0 "$p" 2>/dev/null; do
            code=0
            wait "$p" || code=$?
        done
        [ "$code" -gt "$worst" ] && worst=$code
    done
    pid_of=()
    rm -f "$out/launcher.pid" "$out/pids"
    if [ "$(cat "$runs_root/.cluster.pid" 2>/dev/null)" = "$$" ]; then
        rm -f "$runs_root/.cluster.pid" "$runs_root/.cluster.run"
    fi
    echo "[cluster] stopped: ${reason:-stopped} (worst exit code ${worst}; run folder $out)" >&2
}
# The traps only record the signal; the main loop notices it and stops the cluster outside the
# handler (exiting from inside a trap during `wait` trips a bash bug).
interrupted=""
trap 'interrupted=130' INT
trap 'interrupted=143' TERM

common=(--config "$out/config.toml" --run-id "$run_id" --num-actors "$actors" --parent-pid $$)
rm -f "$out/learner.addr" "$out/selector.addr"
# The last lines of a role's log: its error, without a backtrace (see RUST_LIB_BACKTRACE).
last_error() { tail -n 8 "$out/$1.log" | sed 's/^/    /' >&2; }
wait_addr() {
    for _ in $(seq 300); do
        [ -s "$out/$1.addr" ] && return 0
        kill -0 "${pid_of[$1]}" 2>/dev/null || break
        sleep 0.1
    done
    echo "[cluster] $1 did not start; the end of $out/$1.log:" >&2; last_error "$1"
    reason="the $1 did not start"; stop; exit 1
}
write_pids() {
    for r in "${!pid_of[@]}"; do echo "$r ${pid_of[$r]}"; done > "$out/pids"
}
# Starts (or restarts: $2 = 1) the process of a role. Logs append, so a restart keeps the
# earlier process's log above its own.
start() {
    local role=$1 again=${2:-0} resume_flag=()
    { [ -n "$resume" ] || [ "$again" = 1 ]; } && resume_flag=(--resume)
    case "$role" in
        learner)
            local extra=()
            for d in "${tep_datasets[@]}"; do extra+=(--tep-dataset "$d"); done
            "$bin/terl-learner" "${common[@]}" --addr "$learner_addr" --run-dir "$out" \
                "${extra[@]}" "${resume_flag[@]}" 2>> "$out/learner.log" 9>&- &
            ;;
        selector)
            "$bin/terl-selector" "${common[@]}" --addr "$selector_addr" --run-dir "$out" \
                --learner-addr "$learner_addr" "${resume_flag[@]}" 2>> "$out/selector.log" 9>&- &
            ;;
        actor-*)
            "$bin/terl-actor" "${common[@]}" --actor-id "${role#actor-}" \
                --learner-addr "$learner_addr" 2>> "$out/$role.log" 9>&- &
            ;;
    esac
    pid_of[$role]=$!
    started_at[$role]=$(date +%s)
    write_pids
}

start learner
wait_addr learner
# A restarted learner or selector binds the address the first one got (port 0 resolved), so
# actors and the selector find it again.
learner_addr=$(cat "$out/learner.addr")
# The selector follows the learner's weights (PTR scoring with algorithm = "terl").
start selector
wait_addr selector
selector_addr=$(cat "$out/selector.addr")
for ((i = 0; i < actors; i++)); do start "actor-$i"; done
verb=started; [ -n "$resume" ] && verb=resumed
echo "[cluster] run $run_id $verb: learner $learner_addr, selector $selector_addr, $actors actor(s); logs in $out/. Ctrl-C stops." >&2

# Sleeps $1 seconds unless interrupted.
nap() {
    sleep "$1" 9>&- &
    wait $! || true
}
while [ -z "$interrupted" ]; do
    nap 5
    [ -n "$interrupted" ] && break
    for role in "${!pid_of[@]}"; do
        [ -n "$interrupted" ] && break
        p=${pid_of[$role]}
        kill -0 "$p" 2>/dev/null && continue
        code=0
        wait "$p" || code=$?
        unset "pid_of[$role]"
        write_pids
        [ "$code" -gt "$worst" ] && worst=$code
        if [ "$role" = learner ] && [ "$code" = 0 ]; then
            reason="the learner finished (train.total_env_steps reached)"
            echo "[cluster] $reason; stopping the cluster" >&2
            stop || true
            exit 0
        fi
        n=${restarts_of[$role]:-0}
        # An error exit (not a signal, not a panic) within seconds of a start is a start-up
        # failure that a restart would repeat (a changed config, no checkpoint the run can use,
        # a full disk with on_checkpoint_error = "stop"): stop, and say why.
        if [ "$code" = 1 ] || [ "$code" = 2 ]; then
            if [ $(( $(date +%s) - ${started_at[$role]:-0} )) -lt "$min_uptime" ]; then
                reason="$role (pid $p) exited with code $code within ${min_uptime}s of its start, a failure a restart would repeat"
                echo "[cluster] $reason; stopping the cluster. The end of $out/$role.log:" >&2
                last_error "$role"
                stop || true
                exit 1
            fi
        fi
        if [ "$n" -ge "$restarts" ]; then
            reason="$role (pid $p) exited with code $code after $n restart(s) (limit --restarts $restarts)"
            echo "[cluster] $reason; stopping the cluster (logs in $out/)" >&2
            stop || true
            exit 1
        fi
        wait_s=$(( backoff << n )); [ "$wait_s" -gt 60 ] && wait_s=60
        restarts_of[$role]=$((n + 1))
        echo "[cluster] $role (pid $p) exited with code $code; restart $((n + 1)) of $restarts in ${wait_s}s" >&2
        echo "restart=$(date -Iseconds) role=$role exit_code=$code" >> "$out/cluster.txt"
        nap "$wait_s"
        [ -n "$interrupted" ] && break
        start "$role" 1
    done
    [ -n "$interrupted" ] && break
    echo "---- $(date +%H:%M:%S)" >&2
    "$bin/terl" status --run "$out" >&2 9>&- || true
done
reason="interrupted (signal $((interrupted - 128)))"
stop
exit "$interrupted"
