#!/usr/bin/env bash
# The selector's in-run evaluator on a live MT50 workstation cluster: VmRSS/VmHWM of every process every 5 s.
cd "$(dirname "$0")/../../../.." && mkdir -p "${OUT:-/tmp/mt50-evalmem}"
target/release/terl cluster up --config docs/results/env-memory/live-mt50/config.toml --actors 1 --run-id mt50-evalmem --runs-root ${OUT:-/tmp/mt50-evalmem}/runs > ${OUT:-/tmp/mt50-evalmem}/cluster.log 2>&1 &
L=$!
while kill -0 $L 2>/dev/null; do
  while read -r role pid; do
    [ -r /proc/$pid/status ] || continue
    echo "$(date +%T) $role $pid $(awk '/VmRSS|VmHWM/{printf "%s ", $2}' /proc/$pid/status)"
  done < <(cat ${OUT:-/tmp/mt50-evalmem}/runs/mt50-evalmem/pids 2>/dev/null) >> ${OUT:-/tmp/mt50-evalmem}/process-rss.txt
  sleep 5
done
wait $L; echo "exit $?" >> ${OUT:-/tmp/mt50-evalmem}/process-rss.txt
