#!/usr/bin/env bash
# Soak test: the smoke cluster under repeated faults, then a check that nothing was lost.
#
#   ./deploy/soak.sh [--minutes M] [--kill-every SECS] [--config FILE] [--no-build]
#
# Runs deploy/local-cluster.sh on deploy/configs/cluster-smoke.toml (2 actors, checkpoints every
# few seconds, port 0, a run id of its own; without its training budget) for M minutes (default 10); kills an actor with
# SIGKILL every --kill-every seconds (default 60) and the learner once, half-way. The launcher
# restarts each (the learner resuming from its newest checkpoint). At the end it stops the
# cluster with SIGTERM and checks, printing one line per check:
#   - the learner resumed from the newest checkpoint written before its kill (0 lost
#     checkpointed updates) and trained past it;
#   - every process the launcher started has exited (0 orphans, 0 zombies);
#   - no shared-memory file of the run is left in /dev/shm;
#   - the launcher recorded every restart, and the losses the learner counted are printed.
# Exits 1 if a check fails; the run folder (logs) then stays in runs/soak-<time>-<pid>/ for
# inspection (KEEP_SOAK_RUN=1 keeps it after a pass too).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

minutes=10
kill_every=60
config=deploy/configs/cluster-smoke.toml
build=1
while [ $# -gt 0 ]; do
    case "$1" in
        --minutes) minutes=$2; shift 2 ;;
        --kill-every) kill_every=$2; shift 2 ;;
        --config) config=$2; shift 2 ;;
        --no-build) build=0; shift ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
[[ "$minutes" =~ ^[1-9][0-9]*$ ]] || { echo "--minutes must be a positive integer" >&2; exit 2; }
[[ "$kill_every" =~ ^[1-9][0-9]*$ ]] || { echo "--kill-every must be a positive integer" >&2; exit 2; }
if [ "$build" = 1 ]; then
    ./deploy/setup.sh
    cargo build --release -q -p terl-cli -p terl-learner -p terl-actor -p terl-selector
fi
bin=${CARGO_TARGET_DIR:-target}/release
say() { printf '[soak] %s\n' "$*" >&2; }

run_id=soak-$(date +%Y%m%d-%H%M%S)-$$
out=runs/$run_id
# iceoryx2's files in /dev/shm carry hashes, not run ids: compare the set before and after (a
# concurrent run on the machine that starts meanwhile would be counted too).
shm_set() { ls /dev/shm 2>/dev/null | grep '^iox2_' | grep -v 'global_mgmt$' | sort || true; }
shm_before=$(shm_set)

# The soak runs until it stops the cluster itself: no training budget (total_env_steps = 0).
grep -q '^total_env_steps' "$config" && { say "$config sets total_env_steps; the soak needs a config without a budget"; exit 2; }
soak_config=$(mktemp --suffix=.toml)
trap 'rm -f "$soak_config"' EXIT
if grep -q '^\[train\]' "$config"; then
    sed 's/^\[train\]$/[train]\ntotal_env_steps = 0/' "$config" > "$soak_config"
else
    { cat "$config"; printf '\n[train]\ntotal_env_steps = 0\n'; } > "$soak_config"
fi
./deploy/local-cluster.sh --config "$soak_config" --actors 2 --run-id "$run_id" --no-build \
    --learner-addr 127.0.0.1:0 --selector-addr 127.0.0.1:0 --restarts 100 --restart-backoff 1 \
    > /dev/null 2> "$run_id.launcher.log" &
launcher=$!
# The launcher makes the run folder itself (it refuses one that already holds files): its log
# moves in once the folder is there (the open file follows the move).
for _ in $(seq 300); do [ -s "$out/learner.addr" ] && [ -s "$out/pids" ] && break; sleep 0.2; done
log="$run_id.launcher.log"
if [ -d "$out" ] && mv "$log" "$out/launcher.log" 2>/dev/null; then log="$out/launcher.log"; fi
[ -s "$out/learner.addr" ] || { say "the cluster did not start; see $log"; kill -TERM "$launcher" 2>/dev/null; exit 1; }

status_json() {
    "$bin/terl" status --json --addr "$(cat "$out/learner.addr")" \
        --selector-addr "$(cat "$out/selector.addr")" 2>/dev/null || true
}
json_field() { python3 -c 'import json,sys
d=json.loads(sys.stdin.read() or "{}")
for k in sys.argv[1].split("."):
    d=(d or {}).get(k) if isinstance(d, dict) else None
print("" if d is None else d)' "$1"; }
pid_of() { awk -v r="$1" '$1 == r { print $2 }' "$out/pids" 2>/dev/null; }
newest_checkpoint_update() {
    ls "$out/checkpoints" 2>/dev/null | sed -n 's/^update-0*\([0-9][0-9]*\)\.safetensors$/\1/p' | sort -n | tail -1
}

started=$SECONDS
end=$((started + 60 * minutes))
learner_kill_at=$((started + 30 * minutes))
learner_killed=0
kills=0
before_kill=""
all_pids=()
while [ $SECONDS -lt $end ]; do
    sleep "$(( kill_every < 10 ? kill_every : 10 ))"
    kill -0 "$launcher" 2>/dev/null || { say "the launcher exited early; see $out/launcher.log"; exit 1; }
    for p in $(awk '{ print $2 }' "$out/pids" 2>/dev/null); do all_pids+=("$p"); done
    if [ "$learner_killed" = 0 ] && [ $SECONDS -ge $learner_kill_at ]; then
        before_kill=$(newest_checkpoint_update)
        p=$(pid_of learner)
        say "$(date +%T) kill -9 learner (pid $p); newest checkpoint: update ${before_kill:-none}"
        kill -9 "$p" 2>/dev/null || true
        learner_killed=1
        kills=$((kills + 1))
    elif [ $(( (SECONDS - started) / kill_every )) -gt $(( kills - learner_killed )) ]; then
        role=actor-$(( kills % 2 ))
        p=$(pid_of "$role")
        say "$(date +%T) kill -9 $role (pid $p)"
        kill -9 "$p" 2>/dev/null || true
        kills=$((kills + 1))
    fi
done
# Let the last restart come up, then read the final status.
sleep 5
final=$(status_json)
for p in $(awk '{ print $2 }' "$out/pids" 2>/dev/null); do all_pids+=("$p"); done
kill -TERM "$launcher"
code=0
wait "$launcher" || code=$?
sleep 1

failed=0
check() { if eval "$2"; then say "ok    $1"; else say "FAIL  $1"; failed=1; fi; }
resumed_at=$(echo "$final" | json_field learner.resumed_at_update)
updates=$(echo "$final" | json_field learner.updates)
check "launcher stopped on SIGTERM (exit $code)" '[ "$code" = 143 ]'
check "learner resumed at update ${resumed_at:-?} >= newest checkpoint before its kill (${before_kill:-none}): 0 lost checkpointed updates" \
    '[ -n "$resumed_at" ] && [ "$resumed_at" -ge "${before_kill:-0}" ]'
check "learner trained past the resume point (updates ${updates:-?})" '[ -n "$updates" ] && [ "$updates" -gt "${resumed_at:-0}" ]'
restarts=$(grep -c '^restart=' "$out/cluster.txt" || true)
check "every kill was followed by a restart ($kills kills, $restarts restarts)" '[ "$restarts" -ge "$kills" ]'
orphans=0
zombies=0
for p in $(printf '%s\n' "${all_pids[@]}" | sort -u); do
    stat=$(cat "/proc/$p/stat" 2>/dev/null || true)
    if [[ "$stat" =~ \(terl-[a-z]+\)\ Z ]]; then
        zombies=$((zombies + 1))
    elif [ -n "$stat" ] && tr '\0' ' ' < "/proc/$p/cmdline" 2>/dev/null | grep -q -- "$run_id"; then
        orphans=$((orphans + 1))
    fi
done
check "0 orphans ($orphans) and 0 zombies ($zombies) among $(printf "%s\n" "${all_pids[@]}" | sort -u | grep -c .) started processes" '[ "$orphans" = 0 ] && [ "$zombies" = 0 ]'
leaked=$(comm -13 <(echo "$shm_before") <(shm_set) | grep -c . || true)
check "0 shared-memory files of the run left ($leaked)" '[ "$leaked" = 0 ]'
say "losses the learner counted: rejected batches $(echo "$final" | json_field learner.rejected_batches), env steps $(echo "$final" | json_field learner.env_steps_total)"
if [ "$failed" = 0 ] && [ "${KEEP_SOAK_RUN:-0}" = 0 ]; then
    rm -rf "$out"
else
    say "run folder: $out"
fi
exit "$failed"
