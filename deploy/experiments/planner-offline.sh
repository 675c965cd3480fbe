#!/usr/bin/env bash
# The planner offline (docs/results/planner/): scripted MT10 datasets (200 training episodes per
# task on goal variations 0..40, noise 0.1; 20 held-out episodes per task on variations 40..50),
# then one planner per setting trained on the training set and scored on the held-out one with
# `terl planner eval` (F against the true step gaps; AN alone for 50 episodes per task beside
# random actions).
#
#   deploy/experiments/planner-offline.sh [--out DIR] [--updates N] [--rollouts K] [--only NAME]
#                                         [--no-build]
#
# Settings (each a [tep] value, see crates/rl/src/tep.rs):
#   default      f_target = "gap", relative loss, output scale 100, AN behaviour cloning 1,
#                near goals 50 % within 20 steps (the shipped defaults)
#   gap-bounded  the same with f_target = "gap_bounded" (min(k, 1 + F̃))
#   paper        TepConfig::paper(): Eq. 11–14 exactly (bootstrap, squared loss, scale 1, no
#                behaviour cloning, uniform hindsight goals)
#   no-bc        the default without AN's behaviour cloning (AN minimises F alone, Eq. 14)
# All at 3 × 256 hidden units and minibatch 512 (the workstation TEP size); a setting whose
# eval.json exists is skipped, so the set grows across runs.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
out=docs/results/planner
updates=10000
rollouts=50
only=""
build=1
while [ $# -gt 0 ]; do
    case "$1" in
        --out) out=$2; shift 2 ;;
        --updates) updates=$2; shift 2 ;;
        --rollouts) rollouts=$2; shift 2 ;;
        --only) only=$2; shift 2 ;;
        --no-build) build=0; shift ;;
        -h|--help) sed -n 2,20p "$0"; exit 0 ;;
        *) echo "unknown option $1" >&2; exit 2 ;;
    esac
done
[ "$build" = 1 ] && cargo build --release -q -p terl-cli
terl=${CARGO_TARGET_DIR:-$ROOT/target}/release/terl
[ -x "$terl" ] || { echo "no $terl: build it (cargo build --release -p terl-cli) or drop --no-build" >&2; exit 1; }
data=$out/data
mkdir -p "$data"
say() { printf '[planner-offline] %s\n' "$*" >&2; }

# Datasets are not committed (≈ 65 MB); they are made again in ~40 s, bit for bit.
# Each summary is written beside its committed name and moved there only on success.
dataset() {
    local name=$1
    shift
    [ -f "$data/$name-mt10.mcap" ] && return 0
    "$terl" planner dataset --tasks mt10 "$@" --out "$data/$name-mt10.mcap" > "$out/dataset-$name.txt.tmp"
    mv "$out/dataset-$name.txt.tmp" "$out/dataset-$name.txt"
}
dataset train --episodes-per-task 200 --variations 0..40 --noise 0.1 --seed 0
dataset heldout --episodes-per-task 20 --variations 40..50 --noise 0.1 --seed 1

size=(--set 'f_hidden=[256,256,256]' --set 'an_hidden=[256,256,256]' --set batch_size=512)
settings() {
    case "$1" in
        default) ;;
        gap-bounded) echo "--set f_target=\"gap_bounded\"" ;;
        paper) echo "--set f_target=\"bootstrap\" --set goal_loss=\"squared\" --set f_output_scale=1.0 --set an_bc_weight=0.0 --set near_goal_fraction=0.0" ;;
        no-bc) echo "--set an_bc_weight=0.0" ;;
    esac
}
for name in default gap-bounded paper no-bc; do
    [ -z "$only" ] || [ "$only" = "$name" ] || continue
    dir=$out/$name
    if [ -f "$dir/eval.json" ]; then say "$name: done"; continue; fi
    mkdir -p "$dir"
    # shellcheck disable=SC2046
    cmd=("$terl" planner train --dataset "$data/train-mt10.mcap" --eval-dataset "$data/heldout-mt10.mcap"
        --updates "$updates" --eval-every 1000 "${size[@]}" $(settings "$name") --out "$dir/planner.safetensors")
    say "$name: ${cmd[*]#"$ROOT/"}"
    printf '%q ' "${cmd[@]}" | sed "s|$ROOT/||g" > "$dir/commands.txt"; echo >> "$dir/commands.txt"
    # A trained planner is kept (delete planner.safetensors to train again).
    [ -f "$dir/planner.safetensors" ] || "${cmd[@]}" 2> "$dir/train.log"
    ev=("$terl" planner eval --planner "$dir/planner.safetensors" --dataset "$data/heldout-mt10.mcap"
        --goals "$data/train-mt10.mcap" --rollouts "$rollouts")
    printf '%q ' "${ev[@]}" | sed "s|$ROOT/||g" >> "$dir/commands.txt"; echo >> "$dir/commands.txt"
    "${ev[@]}" --json-out "$dir/eval.json.tmp" > "$dir/eval.txt.tmp"
    mv "$dir/eval.txt.tmp" "$dir/eval.txt"
    mv "$dir/eval.json.tmp" "$dir/eval.json"
    say "$name: $(sed -n '/^all /p' "$dir/eval.txt")"
done
