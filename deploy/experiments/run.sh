#!/usr/bin/env bash
# The paper's protocol (Table I) as commands. Each run is a local cluster
# (deploy/local-cluster.sh) in runs/<experiment>-<algorithm>[-<variant>]-<tasks>-s<seed>/; when
# it ends, its final checkpoint is evaluated on all 50 goal variations of every task
# (`terl eval --json` → eval-final.json). `terl report runs/<experiment>-*` then regenerates the
# table (IQM and mean with stratified bootstrap intervals, mean ± std over seeds, next to the
# paper's numbers; the probability of improvement) and the learning curves.
#
#   deploy/experiments/run.sh mt1-ind [options]   each MT1-Ind task alone (door-open, button-press,
#                                                 pick-place, window-open, sweep-into), MTSAC and
#                                                 TERL; TERL runs also write the PTR-selected TEP
#                                                 datasets (tep-dataset.mcap)
#   deploy/experiments/run.sh mt10 [options]      MTSAC, TERL cold, and TERL started from the
#                                                 MT1-Ind datasets of the same seed, equal budget
#   deploy/experiments/run.sh mt-test [options]   zero-shot: every finished MT10 run's final
#                                                 checkpoint on the MT-Test tasks (no training)
#   deploy/experiments/run.sh mt20 [options]      MTSAC and TERL on MT20
#
# Options:
#   --scale workstation|paper|smoke  networks, batch and budget (default workstation; the configs
#                                    in deploy/configs/experiments/ and deploy/configs/mt10*.toml
#                                    name them; smoke is the scripts' own quick check)
#   --seeds "1 2"                    training seeds (default "1 2")
#   --algorithms "mtsac terl"        (default both)
#   --tasks "door-open-v3 ..."       mt1-ind only: a subset of its tasks
#   --steps N                        override every run's env-step budget
#   --actors N                       actors per run (default: cores - 1, at least 1)
#   --runs-root DIR                  where run folders go (default runs)
#   --tag TAG                        appended to every run id (run ids are machine-wide: two
#                                    experiments at once on one machine need different tags)
#   --no-build                       use the binaries already built
# A run whose eval-final.json exists is skipped, so an interrupted experiment resumes where it
# stopped (a run stopped mid-way starts again from scratch). A run whose id is held by running
# processes is not touched. A failed run does not stop the others; the script then exits 1.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"

usage() { sed -n 2,30p "$0"; }
[ $# -ge 1 ] || { usage >&2; exit 2; }
experiment=$1
shift
scale=workstation
seeds="1 2"
algorithms="mtsac terl"
tasks_override=""
steps=""
cores=$(nproc 2>/dev/null || echo 2)
actors=$(( cores > 1 ? cores - 1 : 1 ))
build=1
runs=runs
tag=""
while [ $# -gt 0 ]; do
    case "$1" in
        --scale) scale=$2; shift 2 ;;
        --seeds) seeds=$2; shift 2 ;;
        --algorithms) algorithms=$2; shift 2 ;;
        --tasks) tasks_override=$2; shift 2 ;;
        --steps) steps=$2; shift 2 ;;
        --actors) actors=$2; shift 2 ;;
        --no-build) build=0; shift ;;
        --runs-root) runs=$2; shift 2 ;;
        --tag) tag=-$2; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
case "$scale" in workstation|paper|smoke) ;; *) echo "--scale must be workstation, paper or smoke" >&2; exit 2 ;; esac
for a in $algorithms; do
    case "$a" in mtsac|terl) ;; *) echo "unknown algorithm $a (mtsac or terl)" >&2; exit 2 ;; esac
done
[ -n "${seeds// /}" ] || { echo "--seeds needs at least one seed" >&2; exit 2; }
[ -n "${algorithms// /}" ] || { echo "--algorithms needs at least one algorithm" >&2; exit 2; }
for s in $seeds; do
    [[ "$s" =~ ^[0-9]+$ ]] || { echo "seeds must be non-negative integers, got $s" >&2; exit 2; }
done
[[ "$actors" =~ ^[1-9][0-9]*$ ]] || { echo "--actors must be a positive integer" >&2; exit 2; }
[[ "$tag" =~ ^(-[A-Za-z0-9_]+)?$ ]] || { echo "--tag takes letters, digits and _" >&2; exit 2; }
[ -z "$tasks_override" ] || [ "$experiment" = mt1-ind ] \
    || { echo "--tasks applies to mt1-ind only" >&2; exit 2; }
[ -z "$steps" ] || [[ "$steps" =~ ^[1-9][0-9]*$ ]] || { echo "--steps must be a positive integer" >&2; exit 2; }

bin=${CARGO_TARGET_DIR:-target}/release
if [ "$build" = 1 ]; then
    ./deploy/setup.sh
    cargo build --release -q -p terl-cli -p terl-learner -p terl-actor -p terl-selector
fi
say() { printf '[experiment] %s\n' "$*" >&2; }

# The base run file of an experiment at the chosen scale.
base_config() {
    local exp=$1
    case "$scale/$exp" in
        smoke/*) echo deploy/configs/experiments/smoke.toml ;;
        workstation/mt1-ind) echo deploy/configs/experiments/mt1-ind-workstation.toml ;;
        paper/mt1-ind) echo deploy/configs/experiments/mt1-ind-paper.toml ;;
        workstation/mt10) echo deploy/configs/mt10-workstation.toml ;;
        paper/mt10) echo deploy/configs/mt10.toml ;;
        workstation/mt20) echo deploy/configs/experiments/mt20-workstation.toml ;;
        paper/mt20) echo deploy/configs/experiments/mt20-paper.toml ;;
    esac
}

# Writes the run file of one run to stdout: the base with its experiment, tasks, algorithm,
# variant, seeds and budget replaced (top-level keys go first, before any [section]).
run_config() {
    local base=$1 exp=$2 tasks=$3 alg=$4 variant=$5 seed=$6
    echo "experiment = \"$exp\""
    echo "tasks = \"$tasks\""
    echo "algorithm = \"$alg\""
    [ -z "$variant" ] || echo "variant = \"$variant\""
    local edits=(-e '/^(experiment|tasks|algorithm|variant) *=/d' -e "s/^seed *=.*/seed = $seed/")
    [ -z "$steps" ] || edits+=(-e "s/^total_env_steps *=.*/total_env_steps = $steps/")
    sed -E "${edits[@]}" "$base"
}

# Trains one run (unless it already has its final evaluation) and evaluates its final checkpoint.
# Extra arguments go to local-cluster.sh (e.g. --tep-dataset FILE).
train_run() {
    local id=$1 config=$2
    shift 2
    local dir="$runs/$id"
    if [ -f "$dir/eval-final.json" ]; then
        cat > /dev/null # the run file on stdin (the writer would fail on a closed pipe)
        say "$id: done already ($dir/eval-final.json)"
        return 0
    fi
    if pgrep -f -- "terl-(learner|selector|actor) .*--run-id $id( |\$)" >/dev/null; then
        cat > /dev/null
        say "$id: processes of a run with this id are still running (another experiment, or a killed one's orphans): not touched"
        return 1
    fi
    rm -rf "$dir"
    mkdir -p "$runs"
    local cfg
    cfg=$(mktemp "${TMPDIR:-/tmp}/terl-$id.XXXXXX.toml") || return 1
    cat > "$cfg" || return 1
    say "$id: training (log: $dir/cluster.log)"
    mkdir -p "$dir"
    local start=$SECONDS
    if ! ./deploy/local-cluster.sh --config "$cfg" --run-id "$id" --actors "$actors" --no-build \
        --learner-addr 127.0.0.1:0 --selector-addr 127.0.0.1:0 --runs-root "$runs" "$@" \
        > "$dir/cluster.log" 2>&1; then
        rm -f "$cfg"
        say "$id: the cluster failed; see $dir/cluster.log"
        return 1
    fi
    rm -f "$cfg"
    echo "train_wall_seconds=$((SECONDS - start))" >> "$dir/cluster.txt"
    say "$id: trained in $((SECONDS - start)) s; evaluating the final checkpoint"
    # (Called in a `||` list, where bash ignores `set -e`: every step checks its status.)
    if ! "$bin/terl" eval --checkpoint "$dir/checkpoints/final.safetensors" --json \
        > "$dir/eval-final.json.tmp"; then
        say "$id: evaluating the final checkpoint failed"
        return 1
    fi
    mv "$dir/eval-final.json.tmp" "$dir/eval-final.json" || return 1
}

mt1_tasks="door-open-v3 button-press-v3 pick-place-v3 window-open-v3 sweep-into-v3"
failed=()

case "$experiment" in
    mt1-ind)
        base=$(base_config mt1-ind)
        tasks=${tasks_override:-$mt1_tasks}
        [ "$scale" = smoke ] && tasks=${tasks_override:-reach-v3}
        for seed in $seeds; do for alg in $algorithms; do for task in $tasks; do
            run_config "$base" mt1-ind "$task" "$alg" "" "$seed" \
                | train_run "mt1-ind-$alg-${task%-v3}-s$seed$tag" "$base" \
                || failed+=("mt1-ind-$alg-${task%-v3}-s$seed$tag")
        done; done; done
        ;;
    mt10|mt20)
        base=$(base_config "$experiment")
        set_tasks=$experiment
        [ "$scale" = smoke ] && set_tasks="reach-v3,push-v3"
        for seed in $seeds; do for alg in $algorithms; do
            run_config "$base" "$experiment" "$set_tasks" "$alg" "" "$seed" \
                | train_run "$experiment-$alg-s$seed$tag" "$base" || failed+=("$experiment-$alg-s$seed$tag")
            if [ "$alg" = terl ] && [ "$experiment" = mt10 ]; then
                datasets=()
                for f in "$runs"/mt1-ind-terl-*-s"$seed$tag"/tep-dataset.mcap; do
                    [ -f "$f" ] && datasets+=(--tep-dataset "$f")
                done
                if [ ${#datasets[@]} -eq 0 ]; then
                    say "no MT1-Ind TERL datasets of seed $seed (run mt1-ind first): skipping TERL from MT1-Ind"
                    continue
                fi
                run_config "$base" "$experiment" "$set_tasks" terl from-mt1-ind "$seed" \
                    | train_run "$experiment-terl-from-mt1-ind-s$seed$tag" "$base" "${datasets[@]}" \
                    || failed+=("$experiment-terl-from-mt1-ind-s$seed$tag")
            fi
        done; done
        ;;
    mt-test)
        # An evaluation-only folder per MT10 run: its config names the evaluated tasks (MT-Test,
        # zero-shot with the uniform task encoding of `terl eval`) and keeps the source run's
        # algorithm, variant and seed, so `terl report` groups it like a run.
        found=0
        test_tasks=mt-test
        [ "$scale" = smoke ] && test_tasks="door-close-v3,lever-pull-v3"
        for src in "$runs"/mt10-*; do
            [ -f "$src/eval-final.json" ] && [ -f "$src/checkpoints/final.safetensors" ] || continue
            found=1
            id="mt-test-from-${src#"$runs"/mt10-}"
            dir="$runs/$id"
            if [ -f "$dir/eval-final.json" ]; then say "$id: done already"; continue; fi
            mkdir -p "$dir"
            {
                echo "experiment = \"mt-test\""
                echo "tasks = \"$test_tasks\""
                sed -E '/^(experiment|tasks) *=/d' "$src/config.toml"
            } > "$dir/config.toml"
            echo "source_run=$src" > "$dir/cluster.txt"
            say "$id: zero-shot evaluation of $src on $test_tasks"
            "$bin/terl" eval --checkpoint "$src/checkpoints/final.safetensors" --tasks "$test_tasks" \
                --json > "$dir/eval-final.json.tmp"
            mv "$dir/eval-final.json.tmp" "$dir/eval-final.json"
        done
        [ "$found" = 1 ] || { say "no finished MT10 run in $runs/mt10-* (run mt10 first)"; exit 1; }
        ;;
    *) echo "unknown experiment $experiment (mt1-ind, mt10, mt-test, mt20)" >&2; exit 2 ;;
esac
if [ ${#failed[@]} -gt 0 ]; then
    say "failed runs (the others finished): ${failed[*]}"
    exit 1
fi
say "done; report: $bin/terl report $runs/$experiment-* --out $runs/report-$experiment"
