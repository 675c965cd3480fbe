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
# --no-build     skip `cargo build --release` (the binaries in target/release are used as they are)
# Logs, the resolved config and checkpoints go to runs/<id>/; progress (terl status) prints every
# few seconds. Ctrl-C (or `terl cluster down [ID]`) stops every process and waits for them; the
# services also stop by themselves if the launcher is killed (they follow its pid). With
# algorithm = "terl" the selected samples also go to runs/<id>/tep-dataset.mcap.
#
# This script builds the release binaries and then becomes `target/release/terl cluster up` with
# the same options (same pid): the launcher itself is Rust (services/cli/src/cluster/launcher.rs).
# Exit codes: 0 when the training budget is reached or `terl cluster down` stopped the run, 1
# when a process did not start or died too often, 2 for bad options, 130/143 on SIGINT/SIGTERM.
# `terl cluster clean ID` removes the launcher files of a run whose launcher was killed.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"

build=1
for arg in "$@"; do
    case "$arg" in
        --no-build) build=0 ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
    esac
done
bin=${CARGO_TARGET_DIR:-target}/release
if [ "$build" = 1 ]; then
    ./deploy/setup.sh
    missing=0
    for b in terl terl-learner terl-actor terl-selector; do
        [ -x "$bin/$b" ] || missing=1
    done
    if [ "$missing" = 1 ]; then
        echo "[cluster] building release binaries (first time from cold: 12–17 minutes on 2 cores)" >&2
    else
        echo "[cluster] bringing the release binaries up to date (seconds; minutes after source changes)" >&2
    fi
    # Cargo's own progress on a terminal; quiet in logs.
    quiet=-q
    [ -t 2 ] && quiet=
    cargo build --release $quiet -p terl-cli -p terl-learner -p terl-actor -p terl-selector
fi
[ -x "$bin/terl" ] || { echo "$bin/terl not found: build it (run without --no-build)" >&2; exit 2; }
exec "$bin/terl" cluster up "$@"
