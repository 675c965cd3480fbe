#!/usr/bin/env bash
# Cluster throughput by actor count: env steps/s, updates/s, and each process's CPU use and
# memory, for the MT10 and MT50 workstation run files, with 1, 2 and 4 actors on this machine.
# Each cluster trains until stopped with the in-run evaluation off (a throughput measurement);
# after a warm-up of a third of --seconds, `terl status --json` is read every 5 s and the
# medians of those readings are one JSON line of --out.
#
#   deploy/bench/scaling.sh [--sets "mt10 mt50"] [--actors "1 2 4"] [--seconds 120]
#                           [--out docs/results/scaling/clusters.jsonl]
#
# Needs the release binaries (./deploy/local-cluster.sh or cargo build --release builds them).
# Run on an otherwise idle machine: every cluster shares its cores with whatever else runs.
# Ctrl-C or SIGTERM stops the cluster being measured; after a kill -9 of this script its cluster
# keeps running (it trains until stopped): `terl cluster down scaling-<set>-a<N> --runs-root
# <the /tmp/terl-scaling.* folder>` stops it.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
sets="mt10 mt50"
actor_counts="1 2 4"
seconds=120
out=docs/results/scaling/clusters.jsonl
while [ $# -gt 0 ]; do
    case "$1" in --sets|--actors|--seconds|--out) [ $# -ge 2 ] || { echo "$1 needs a value" >&2; exit 2; } ;; esac
    case "$1" in
        --sets) sets=$2; shift 2 ;;
        --actors) actor_counts=$2; shift 2 ;;
        --seconds) seconds=$2; shift 2 ;;
        --out) out=$2; shift 2 ;;
        -h|--help) sed -n '2,12p' "$0"; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
[[ "$seconds" =~ ^[1-9][0-9]{1,4}$ ]] && [ "$seconds" -ge 30 ] || { echo "--seconds takes 30 to 99999" >&2; exit 2; }
[ -n "${sets// /}" ] || { echo "--sets needs at least one task set" >&2; exit 2; }
[ -n "${actor_counts// /}" ] || { echo "--actors needs at least one count" >&2; exit 2; }
most=$((4 * $(nproc)))
for n in $actor_counts; do
    [[ "$n" =~ ^[1-9][0-9]{0,3}$ ]] && [ "$n" -le "$most" ] \
        || { echo "--actors takes counts from 1 to $most (4 per core, as the launcher)" >&2; exit 2; }
done
for s in $sets; do
    [ -f "deploy/configs/$s-workstation.toml" ] || { echo "no deploy/configs/$s-workstation.toml" >&2; exit 2; }
done
bin=${CARGO_TARGET_DIR:-target}/release
[ -x "$bin/terl" ] || { echo "$bin/terl is missing: build the release binaries first" >&2; exit 1; }
root=$(mktemp -d "${TMPDIR:-/tmp}/terl-scaling.XXXXXX")
launcher=""
# SIGTERM stops a launcher (SIGINT is ignored by background jobs of a script).
cleanup() {
    [ -z "$launcher" ] || kill -TERM "$launcher" 2>/dev/null || true
    [ -z "$launcher" ] || wait "$launcher" 2>/dev/null || true
    rm -rf "$root"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
mkdir -p "$(dirname "$out")"
cores=$(nproc)
for set in $sets; do
    for n in $actor_counts; do
        id="scaling-$set-a$n"
        cfg="$root/$id.toml"
        sed -E -e 's/^total_env_steps *=.*/total_env_steps = 0/' \
            -e 's/^eval_every_env_steps *=.*/eval_every_env_steps = 0/' \
            "deploy/configs/$set-workstation.toml" > "$cfg"
        echo "[scaling] $set, $n actor(s): $seconds s" >&2
        "$bin/terl" cluster up --config "$cfg" --run-id "$id" --actors "$n" --runs-root "$root" \
            --learner-addr 127.0.0.1:0 --selector-addr 127.0.0.1:0 > "$root/$id.log" 2>&1 &
        launcher=$!
        sleep $((seconds / 3))
        if ! kill -0 "$launcher" 2>/dev/null; then
            echo "[scaling] the cluster did not start:" >&2
            tail -5 "$root/$id.log" >&2
            exit 1
        fi
        end=$((SECONDS + seconds - seconds / 3))
        : > "$root/$id.status"
        while [ $SECONDS -lt $end ]; do
            "$bin/terl" status --json --run "$root/$id" >> "$root/$id.status" 2>/dev/null || true
            sleep 5
        done
        kill -TERM "$launcher" 2>/dev/null || true
        wait "$launcher" || true
        launcher=""
        python3 - "$set" "$n" "$cores" "$seconds" "$root/$id.status" >> "$out" <<'PY'
import json, statistics, sys
task_set, actors, cores, seconds, path = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
rows = [json.loads(l) for l in open(path) if l.strip()]
rows = [r for r in rows if r.get("learner") and r["learner"].get("updates_per_second", 0) > 0]
if not rows:
    sys.exit(f"no status reading with updates for {task_set} × {actors}")
med = lambda xs: statistics.median(xs) if xs else None
roles = {}
for r in rows:
    for p in (r.get("launcher") or {}).get("processes", []):
        role = "actor" if p["role"].startswith("actor") else p["role"]
        if p.get("cpu_cores") is not None:
            roles.setdefault(role, {"cpu": [], "rss": []})
            roles[role]["cpu"].append(p["cpu_cores"])
            roles[role]["rss"].append(p["rss_mb"])
print(json.dumps({
    "tasks": task_set, "actors": actors, "cores": cores, "seconds": seconds, "readings": len(rows),
    "env_steps_per_second": med([sum(a["env_steps_per_second"] for a in r["learner"]["actors"]) for r in rows]),
    "updates_per_second": med([r["learner"]["updates_per_second"] for r in rows]),
    "busy_updates_per_second": med([r["learner"]["busy_updates_per_second"] for r in rows]),
    "cpu_cores": {k: med(v["cpu"]) for k, v in roles.items()},
    "rss_mb": {k: med(v["rss"]) for k, v in roles.items()},
}, sort_keys=True))
PY
    done
done
echo "[scaling] wrote $out" >&2
