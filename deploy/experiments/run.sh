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
#   deploy/experiments/run.sh terl-pipeline [options]
#                                                 the paper's two stages: (1) each MT1-Ind task
#                                                 alone (TERL) until its planner gate opens and it
#                                                 has selected --stage1-samples transitions (the
#                                                 budget is the cap); (2) the planner trained
#                                                 offline on the five PTR-selected datasets
#                                                 (terl planner train) and checked on trajectories
#                                                 held out of them (terl planner eval); (3) MT10
#                                                 TERL from that planner (variant "pipeline"),
#                                                 guiding each task the planner passes from the
#                                                 first step
#
# Options:
#   --scale workstation|paper|smoke  networks, batch and budget (default workstation; the configs
#                                    in deploy/configs/experiments/ and deploy/configs/mt10*.toml
#                                    name them; smoke is the scripts' own quick check)
#   --seeds "1 2"                    training seeds (default "1 2")
#   --algorithms "mtsac terl care"   any of mtsac, terl and care (CARE, the paper's third row;
#                                    [sac.care] of the base file or CARE's MT10 defaults);
#                                    default "mtsac terl"
#   --tasks "door-open-v3 ..."       mt1-ind only: a subset of its tasks
#   --steps N                        override every run's env-step budget
#   --actors N                       actors per run (default: cores - 1, at least 1)
#   --runs-root DIR                  where run folders go (default runs)
#   --tag TAG                        appended to every run id (run ids are machine-wide: two
#                                    experiments at once on one machine need different tags)
#   --no-build                       use the binaries already built
#   --stage1-samples N               terl-pipeline: selected transitions per MT1-Ind task before
#                                    stage 1 stops (default: smoke 200, workstation 20000,
#                                    paper 100000)
#   --planner-updates N              terl-pipeline: offline planner updates (default: smoke 300,
#                                    workstation 20000, paper 50000)
#   --last-stage 1|2|3               terl-pipeline: stop after this stage (default 3)
#   --stage1-steps N                 terl-pipeline: the env-step cap of each stage-1 run only
#                                    (--steps sets every run's budget, stage 3's included)
#   --planner-from-seed K            terl-pipeline: stage 3 only, for every seed of --seeds, from the
#                                    planner (and stage-1 datasets) of seed K's stages 1 and 2,
#                                    which must be done: MT10 seeds that share one planner
#   --learner-threads N|auto         every run's [sac] threads (the learner's cores; default: the
#                                    base run file's, "auto" at workstation and paper scale); use
#                                    it with --tag, the run id does not name it
#   --mode reproducible|asynchronous MTSAC and CARE runs with [cluster] reproducible = true (the
#                                    default: the same seed gives the same run bit for bit, at
#                                    about 10 % more wall time on MT10 workstation) or
#                                    asynchronous; TERL runs are asynchronous
#                                    (docs/cluster.md#reproducible-runs)
#   --variant NAME                   mt1-ind, mt10, mt20: the run file's variant of the runs
#                                    that have none of their own (1 to 24 lower-case letters and
#                                    digits), also in their run ids, so `terl report` groups them
#                                    apart from the same algorithm without it, e.g.
#                                    --mode asynchronous --variant asynchronous beside the default
#                                    reproducible runs; MT10 TERL from MT1-Ind uses the MT1-Ind
#                                    TERL datasets of the same variant
# A run whose eval-final.json exists is skipped, so an interrupted experiment resumes where it
# stopped (a run stopped mid-way starts again from scratch). A run whose id is held by running
# processes is not touched. A failed run does not stop the others; the script then exits 1.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"

usage() { sed -n '2,/^set -euo pipefail/{/^set -euo/!p}' "$0"; }
[ $# -ge 1 ] || { usage >&2; exit 2; }
case "$1" in -h|--help) usage; exit 0 ;; esac
experiment=$1
shift
case "$experiment" in
    mt1-ind|mt10|mt20|mt-test|terl-pipeline) ;;
    *) echo "unknown experiment $experiment (mt1-ind, mt10, mt20, mt-test or terl-pipeline; see --help)" >&2; exit 2 ;;
esac
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
stage1_samples=""
planner_updates=""
last_stage=3
stage1_steps=""
planner_from=""
planner_from_set=0
mode=reproducible
learner_threads=""
variant=""
while [ $# -gt 0 ]; do
    case "$1" in
        --no-build|-h|--help) ;;
        --*) [ $# -ge 2 ] || { echo "$1 needs a value (see --help)" >&2; exit 2; } ;;
    esac
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
        --stage1-samples) stage1_samples=$2; shift 2 ;;
        --planner-updates) planner_updates=$2; shift 2 ;;
        --last-stage) last_stage=$2; shift 2 ;;
        --stage1-steps) stage1_steps=$2; shift 2 ;;
        --mode) mode=$2; shift 2 ;;
        --variant) variant=$2; shift 2 ;;
        --learner-threads) learner_threads=$2; shift 2 ;;
        --planner-from-seed) planner_from=$2; planner_from_set=1; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
case "$scale" in workstation|paper|smoke) ;; *) echo "--scale must be workstation, paper or smoke" >&2; exit 2 ;; esac
case "$mode" in reproducible|asynchronous) ;; *) echo "--mode must be reproducible or asynchronous" >&2; exit 2 ;; esac
if [ -n "$variant" ]; then
    case "$variant" in
        *[!a-z0-9]*) echo "--variant must be 1 to 24 lower-case letters and digits (got \"$variant\")" >&2; exit 2 ;;
    esac
    [ ${#variant} -le 24 ] || { echo "--variant must be 1 to 24 lower-case letters and digits (got ${#variant} characters)" >&2; exit 2; }
    case "$experiment" in
        mt-test|terl-pipeline) echo "--variant applies to mt1-ind, mt10 and mt20 runs, not to $experiment" >&2; exit 2 ;;
    esac
fi
for a in $algorithms; do
    case "$a" in mtsac|terl|care) ;; *) echo "unknown algorithm $a (mtsac, terl or care)" >&2; exit 2 ;; esac
done
[ -n "${seeds// /}" ] || { echo "--seeds needs at least one seed" >&2; exit 2; }
[ -n "${algorithms// /}" ] || { echo "--algorithms needs at least one algorithm" >&2; exit 2; }
for s in $seeds; do
    [[ "$s" =~ ^[0-9]+$ ]] || { echo "seeds must be non-negative integers, got $s" >&2; exit 2; }
done
[ -z "$learner_threads" ] || [ "$learner_threads" = auto ] || [[ "$learner_threads" =~ ^[1-9][0-9]{0,2}$ ]] \
    || { echo "--learner-threads takes auto or a positive integer" >&2; exit 2; }
[[ "$actors" =~ ^[1-9][0-9]*$ ]] || { echo "--actors must be a positive integer" >&2; exit 2; }
[[ "$tag" =~ ^(-[A-Za-z0-9_]+)?$ ]] || { echo "--tag takes letters, digits and _" >&2; exit 2; }
[ -z "$tasks_override" ] || [ "$experiment" = mt1-ind ] \
    || { echo "--tasks applies to mt1-ind only" >&2; exit 2; }
[ -z "$steps" ] || [[ "$steps" =~ ^[1-9][0-9]{0,14}$ ]] || { echo "--steps must be a positive integer (at most 15 digits)" >&2; exit 2; }
[[ "$last_stage" =~ ^[123]$ ]] || { echo "--last-stage takes 1, 2 or 3" >&2; exit 2; }
for v in "$stage1_samples" "$planner_updates" "$stage1_steps"; do
    [ -z "$v" ] || [[ "$v" =~ ^[1-9][0-9]{0,14}$ ]] \
        || { echo "--stage1-samples, --stage1-steps and --planner-updates take positive integers (at most 15 digits)" >&2; exit 2; }
done
[ "$planner_from_set" = 0 ] || [[ "$planner_from" =~ ^[0-9]{1,15}$ ]] \
    || { echo "--planner-from-seed takes a seed (a non-negative integer of at most 15 digits)" >&2; exit 2; }
[ "$planner_from_set" = 0 ] || [ "$last_stage" = 3 ] \
    || { echo "--planner-from-seed runs stage 3 only: it does not go with --last-stage" >&2; exit 2; }
if [ "$experiment" != terl-pipeline ] \
    && { [ -n "$stage1_samples$planner_updates$stage1_steps$planner_from" ] || [ "$last_stage" != 3 ]; }; then
    echo "--stage1-samples, --stage1-steps, --planner-updates, --planner-from-seed and --last-stage apply to terl-pipeline only" >&2
    exit 2
fi

bin=${CARGO_TARGET_DIR:-target}/release
if [ "$build" = 1 ]; then
    ./deploy/setup.sh
    cargo build --release -q -p terl-cli -p terl-learner -p terl-actor -p terl-selector
fi
say() { printf '[experiment] %s\n' "$*" >&2; }
# Temporary run files go with the script, however it ends.
current_tmp=""
cfg3=""
trap 'rm -f "$current_tmp" "$cfg3"' EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# One instance per experiment and tag in a runs root: a second one would delete the first one's
# run folders as unfinished.
mkdir -p "$runs"
exec 9> "$runs/.run-$experiment$tag.lock"
flock -n 9 || { say "another run.sh $experiment${tag:+ (tag ${tag#-})} is running on $runs; wait for it or use another --tag"; exit 1; }

# The base run file of an experiment at the chosen scale.
base_config() {
    local exp=$1
    case "$scale/$exp" in
        smoke/pipeline-stage1) echo deploy/configs/experiments/pipeline-stage1-smoke.toml ;;
        smoke/*) echo deploy/configs/experiments/smoke.toml ;;
        workstation/mt1-ind) echo deploy/configs/experiments/mt1-ind-workstation.toml ;;
        paper/mt1-ind) echo deploy/configs/experiments/mt1-ind-paper.toml ;;
        workstation/mt10) echo deploy/configs/mt10-workstation.toml ;;
        paper/mt10) echo deploy/configs/mt10.toml ;;
        workstation/mt20) echo deploy/configs/experiments/mt20-workstation.toml ;;
        paper/mt20) echo deploy/configs/experiments/mt20-paper.toml ;;
        workstation/pipeline-stage1) echo deploy/configs/experiments/pipeline-stage1-workstation.toml ;;
        paper/pipeline-stage1) echo deploy/configs/experiments/mt1-ind-paper.toml ;;
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
    if [ -n "$learner_threads" ]; then
        local t=$learner_threads
        [ "$t" = auto ] && t='"auto"'
        if sed -n '/^\[sac\]$/,/^\[/p' "$base" | grep -q '^threads *='; then
            edits+=(-e "/^\\[sac\\]\$/,/^\\[/s/^threads *=.*/threads = $t/")
        else
            edits+=(-e "s/^\\[sac\\]\$/[sac]\\nthreads = $t/")
        fi
    fi
    if [ "$alg" != terl ] && [ "$mode" = reproducible ]; then
        edits+=(-e '/^reproducible *=/d')
        if grep -q '^\[cluster\]$' "$base"; then
            edits+=(-e 's/^\[cluster\]$/[cluster]\nreproducible = true/')
            sed -E "${edits[@]}" "$base"
        else
            sed -E "${edits[@]}" "$base"
            printf '\n[cluster]\nreproducible = true\n'
        fi
        return
    fi
    sed -E "${edits[@]}" "$base"
}

# Trains one run (unless it already has its final evaluation) and evaluates its final checkpoint.
# Extra arguments go to local-cluster.sh (e.g. --tep-dataset FILE).
train_run() {
    local id=$1 config=$2
    shift 2
    local dir="$runs/$id"
    if [ ${#id} -gt 64 ]; then
        cat > /dev/null
        say "$id: a run id has at most 64 characters (shorten --tag or --variant)"
        return 1
    fi
    if [ -f "$dir/eval-final.json" ]; then
        # The run file on stdin (read whole: the writer would fail on a closed pipe) must be the
        # finished run's, so that a run of other settings under the same id is never skipped.
        local want have
        want=$(grep -E '^(experiment|tasks|algorithm|variant) *=' | sort)
        have=$(grep -E '^(experiment|tasks|algorithm|variant) *=' "$dir/config.toml" 2>/dev/null | sort)
        if [ "$want" != "$have" ]; then
            say "$id: $dir holds a finished run of other settings ($(echo $have)); not touched"
            return 1
        fi
        say "$id: done already ($dir/eval-final.json)"
        return 0
    fi
    if pgrep -f -- "terl-(learner|selector|actor) .*--run-id $id( |\$)" >/dev/null; then
        cat > /dev/null
        say "$id: processes of a run with this id are still running (another experiment, or a killed one's orphans): not touched"
        return 1
    fi
    rm -rf "$dir" "$runs/$id.cluster.log"
    mkdir -p "$runs"
    local cfg
    cfg=$(mktemp "${TMPDIR:-/tmp}/terl-$id.XXXXXX.toml") || return 1
    current_tmp=$cfg
    cat > "$cfg" || return 1
    # The launcher refuses a run folder that already holds files, so the launcher's own output
    # goes beside the folder while it runs and into it afterwards.
    local log="$runs/$id.cluster.log"
    rm -f "$log"
    say "$id: training (log: $log)"
    local start=$SECONDS
    local rc=0
    ./deploy/local-cluster.sh --config "$cfg" --run-id "$id" --actors "$actors" --no-build \
        --learner-addr 127.0.0.1:0 --selector-addr 127.0.0.1:0 --runs-root "$runs" "$@" \
        > "$log" 2>&1 || rc=$?
    if [ -d "$dir" ]; then
        mv "$log" "$dir/cluster.log" && log="$dir/cluster.log"
    fi
    if [ "$rc" != 0 ]; then
        rm -f "$cfg"
        # Stopped by Ctrl-C or SIGTERM (the launcher exits 130 or 143): the whole experiment stops.
        if [ "$rc" = 130 ] || [ "$rc" = 143 ]; then
            say "$id: interrupted; stopping the experiment (run it again to continue)"
            exit "$rc"
        fi
        say "$id: the cluster failed; see $log"
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

# A string as the replacement of a sed `s|…|…|` (escapes \, & and |).
sed_replacement() { local v=${1//\\/\\\\}; v=${v//&/\\&}; printf '%s' "${v//|/\\|}"; }

# Selected samples a finished run's learner received (its last "trainer stopped" line), or
# "unknown" for logs that predate the field.
selected_of() {
    local n
    n=$(grep -ho 'trainer stopped.*selected_samples=[0-9]*' "$1/learner.log" 2>/dev/null | tail -1 | sed 's/.*selected_samples=//')
    [ -n "$n" ] && echo "$n" || echo unknown
}
failed=()

case "$experiment" in
    mt1-ind)
        base=$(base_config mt1-ind)
        tasks=${tasks_override:-$mt1_tasks}
        [ "$scale" = smoke ] && tasks=${tasks_override:-reach-v3}
        for seed in $seeds; do for alg in $algorithms; do for task in $tasks; do
            id="mt1-ind-$alg${variant:+-$variant}-${task%-v3}-s$seed$tag"
            run_config "$base" mt1-ind "$task" "$alg" "$variant" "$seed" \
                | train_run "$id" "$base" || failed+=("$id")
        done; done; done
        ;;
    mt10|mt20)
        base=$(base_config "$experiment")
        set_tasks=$experiment
        [ "$scale" = smoke ] && set_tasks="reach-v3,push-v3"
        for seed in $seeds; do for alg in $algorithms; do
            run_config "$base" "$experiment" "$set_tasks" "$alg" "$variant" "$seed" \
                | train_run "$experiment-$alg${variant:+-$variant}-s$seed$tag" "$base" \
                || failed+=("$experiment-$alg${variant:+-$variant}-s$seed$tag")
            if [ "$alg" = terl ] && [ "$experiment" = mt10 ]; then
                datasets=()
                for f in "$runs"/mt1-ind-terl-*-s"$seed$tag"/tep-dataset.mcap; do
                    # Only the MT1-Ind runs of this variant (or of none, without --variant).
                    [ -f "$f" ] || continue
                    v=$(sed -n 's/^variant *= *"\(.*\)".*/\1/p' "$(dirname "$f")/config.toml")
                    [ "$v" = "$variant" ] && datasets+=(--tep-dataset "$f")
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
    terl-pipeline)
        case "$scale" in
            smoke) s1_default=200; updates_default=300; stage3_tasks="reach-v3,push-v3"
                   s1_tasks="reach-v3 push-v3"; hold_out=1; rollouts=2 ;;
            workstation) s1_default=20000; updates_default=20000; stage3_tasks=mt10
                   s1_tasks=$mt1_tasks; hold_out=4; rollouts=20 ;;
            paper) s1_default=100000; updates_default=50000; stage3_tasks=mt10
                   s1_tasks=$mt1_tasks; hold_out=4; rollouts=50 ;;
        esac
        s1_samples=${stage1_samples:-$s1_default}
        p_updates=${planner_updates:-$updates_default}
        base1=$(base_config pipeline-stage1)
        base3=$(base_config mt10)
        [ "$scale" = smoke ] && base3=deploy/configs/experiments/smoke.toml
        # The stage-3 task names (a set name like mt10 expands through `terl env list`).
        stage3_names=$("$bin/terl" env list --json | python3 -c '
import json, sys
spec, info = sys.argv[1], json.load(sys.stdin)
names = info["task_sets"].get(spec) or spec.split(",")
print(" ".join(names))' "$stage3_tasks")
        if [ -n "$planner_from" ]; then
            # Stage 3 only, every seed from seed K's planner and stage-1 datasets.
            planner_dir="$runs/pipeline-planner-s$planner_from$tag"
            [ -f "$planner_dir/planner.safetensors" ] && [ -f "$planner_dir/eval.json" ] || {
                say "$planner_dir has no finished planner: run terl-pipeline --seeds $planner_from first"
                exit 1
            }
            planner="$(cd "$planner_dir" && pwd)/planner.safetensors"
            planner_sum=$(md5sum < "$planner")
            stage3_datasets=()
            for task in $s1_tasks; do
                f="$runs/pipeline-stage1-${task%-v3}-s$planner_from$tag/tep-dataset.mcap"
                if [ -s "$f" ]; then
                    case " $stage3_names " in *" $task "*) stage3_datasets+=(--tep-dataset "$f") ;; esac
                fi
            done
            for seed in $seeds; do
                id3="mt10-terl-pipeline-s$seed$tag"
                if [ -f "$runs/$id3/eval-final.json" ]; then
                    if [ ! -f "$runs/$id3/planner.md5" ] || [ "$(cat "$runs/$id3/planner.md5")" != "$planner_sum" ]; then
                        say "$id3: done with another planner; not touched (remove $runs/$id3 to train it again)"
                    else
                        say "$id3: done already ($runs/$id3/eval-final.json)"
                    fi
                    continue
                fi
                cfg3=$(mktemp "${TMPDIR:-/tmp}/terl-stage3-s$seed.XXXXXX.toml")
                run_config "$base3" mt10 "$stage3_tasks" terl pipeline "$seed" \
                    | sed -E -e '/^init_planner *=/d' \
                        -e "s|^\[tep\]\$|[tep]\ninit_planner = \"$(sed_replacement "$planner")\"|" > "$cfg3"
                grep -q '^init_planner' "$cfg3" || printf '\n[tep]\ninit_planner = "%s"\n' "$planner" >> "$cfg3"
                [ "$scale" != smoke ] || grep -q '^\[guidance\]' "$cfg3" \
                    || printf '\n[guidance]\nmin_spearman = -1.0\nvalidation_trajectories = 1\n' >> "$cfg3"
                if train_run "$id3" "$base3" "${stage3_datasets[@]}" < "$cfg3"; then
                    printf '%s\n' "$planner_sum" > "$runs/$id3/planner.md5"
                    echo "planner_from_seed=$planner_from" >> "$runs/$id3/cluster.txt"
                else
                    failed+=("$id3")
                fi
                rm -f "$cfg3"
            done
            seeds=""
        fi
        for seed in $seeds; do
            # Stage 1: each task alone until its planner data is usable.
            datasets=()
            stage3_datasets=()
            stage1_failed=0
            for task in $s1_tasks; do
                id="pipeline-stage1-${task%-v3}-s$seed$tag"
                f="$runs/$id/tep-dataset.mcap"
                if [ -f "$runs/$id/eval-final.json" ] && [ ! -f "$f" ]; then
                    say "$id: finished but its TEP dataset is missing: training it again"
                    rm -f "$runs/$id/eval-final.json"
                fi
                s1_cap=(-e '')
                [ -z "$stage1_steps" ] || s1_cap=(-e "s/^total_env_steps *=.*/total_env_steps = $stage1_steps/")
                if run_config "$base1" pipeline-stage1 "$task" terl "" "$seed" \
                    | sed -E -e '/^stop_at_planner_samples_per_task *=/d' "${s1_cap[@]}" \
                        -e "s/^\[cluster\]\$/[cluster]\nstop_at_planner_samples_per_task = $s1_samples/" \
                    | train_run "$id" "$base1"; then
                    grep -h "planner ready\|training budget reached" "$runs/$id/learner.log" 2>/dev/null \
                        | tail -1 | sed "s/^/[experiment] $id: /" >&2 || true
                    n=$(selected_of "$runs/$id")
                    if [ "$n" = 0 ] || [ ! -s "$f" ]; then
                        say "$id: selected nothing within its budget (PTR's gate never opened): no data for the planner"
                    else
                        datasets+=(--dataset "$f")
                        case " $stage3_names " in *" $task "*) stage3_datasets+=(--tep-dataset "$f") ;; esac
                    fi
                else
                    failed+=("$id")
                    stage1_failed=1
                fi
            done
            if [ "$stage1_failed" = 1 ]; then
                say "seed $seed: stage 1 is incomplete (see above); stages 2 and 3 wait for it"
                continue
            fi
            if [ ${#datasets[@]} -eq 0 ]; then
                say "seed $seed: stage 1 gave no dataset; stages 2 and 3 skipped"
                continue
            fi
            [ "$last_stage" -ge 2 ] || continue
            # Stage 3's run file first: stage 2 trains with its [tep] networks.
            planner_dir="$runs/pipeline-planner-s$seed$tag"
            mkdir -p "$planner_dir"
            planner="$(cd "$planner_dir" && pwd)/planner.safetensors"
            stage3_cfg="$planner_dir/stage3.toml"
            run_config "$base3" mt10 "$stage3_tasks" terl pipeline "$seed" \
                | sed -E -e '/^init_planner *=/d' \
                    -e "s|^\[tep\]\$|[tep]\ninit_planner = \"$(sed_replacement "$planner")\"|" > "$stage3_cfg"
            grep -q '^init_planner' "$stage3_cfg" \
                || printf '\n[tep]\ninit_planner = "%s"\n' "$planner" >> "$stage3_cfg"
            # Smoke scale: a planner of a few hundred updates on tiny networks does not reach
            # ρ ≥ 0.8, so the check passes at once there (as in smoke-terl.toml) and the path runs.
            [ "$scale" != smoke ] || grep -q '^\[guidance\]' "$stage3_cfg" \
                || printf '\n[guidance]\nmin_spearman = -1.0\nvalidation_trajectories = 1\n' >> "$stage3_cfg"
            # Stage 2: the planner offline, checked on held-out selected trajectories (stage 3's
            # [tep] without its init_planner, which names the file stage 2 writes).
            grep -v '^init_planner' "$stage3_cfg" > "$planner_dir/planner.toml"
            # Stage 2 is done when its planner and evaluation exist and were made from the same
            # stage-1 datasets as now (a redone stage-1 run makes it train again).
            inputs=$(for ((i = 1; i < ${#datasets[@]}; i += 2)); do md5sum "${datasets[i]}"; done)
            if [ -f "$planner_dir/eval.json" ] && [ -f "$planner" ] \
                && { [ ! -f "$planner_dir/inputs.md5" ] || [ "$(cat "$planner_dir/inputs.md5")" = "$inputs" ]; }; then
                [ -f "$planner_dir/inputs.md5" ] || printf '%s\n' "$inputs" > "$planner_dir/inputs.md5"
                say "pipeline-planner-s$seed$tag: done already"
            else
                rm -f "$planner_dir/eval.json" "$planner"
                printf '%s\n' "$inputs" > "$planner_dir/inputs.md5"
                say "pipeline-planner-s$seed$tag: training the planner on $(( ${#datasets[@]} / 2 )) stage-1 datasets ($p_updates updates)"
                printf '%s\n' "$bin/terl planner train ${datasets[*]} --hold-out-trajectories $hold_out --config $planner_dir/planner.toml --updates $p_updates --seed $seed --out $planner" \
                    "$bin/terl planner eval --planner $planner ${datasets[*]} --hold-out-trajectories $hold_out --rollouts $rollouts" \
                    > "$planner_dir/commands.txt"
                if "$bin/terl" planner train "${datasets[@]}" --hold-out-trajectories "$hold_out" \
                        --config "$planner_dir/planner.toml" --updates "$p_updates" --seed "$seed" --out "$planner" \
                        > "$planner_dir/train.log" 2>&1 \
                    && "$bin/terl" planner eval --planner "$planner" "${datasets[@]}" \
                        --hold-out-trajectories "$hold_out" --rollouts "$rollouts" \
                        --json-out "$planner_dir/eval.json.tmp" > "$planner_dir/eval.txt" 2>"$planner_dir/eval.log"; then
                    mv "$planner_dir/eval.json.tmp" "$planner_dir/eval.json"
                    say "pipeline-planner-s$seed$tag: F on the held-out trajectories: $(awk '$1 == "all" { print "ρ " $3 " over " $2 " pairs" }' "$planner_dir/eval.txt")"
                else
                    say "pipeline-planner-s$seed$tag: the planner stage failed; see $planner_dir"
                    failed+=("pipeline-planner-s$seed$tag")
                    continue
                fi
            fi
            [ "$last_stage" -ge 3 ] || continue
            # Stage 3: MT10 TERL from the planner; the stage-1 datasets of MT10's tasks give the
            # learner held-out trajectories to validate the planner on at start.
            # Done only from this planner: a changed one (stage 2 redone) trains stage 3 again.
            id3="mt10-terl-pipeline-s$seed$tag"
            planner_sum=$(md5sum < "$planner")
            if [ -f "$runs/$id3/eval-final.json" ] && [ -f "$runs/$id3/planner.md5" ] \
                && [ "$(cat "$runs/$id3/planner.md5")" != "$planner_sum" ]; then
                say "$id3: its planner changed since it ran (stage 2 was redone): training it again"
                rm -f "$runs/$id3/eval-final.json"
            fi
            if train_run "$id3" "$base3" "${stage3_datasets[@]}" < "$stage3_cfg"; then
                [ -f "$runs/$id3/planner.md5" ] || printf '%s\n' "$planner_sum" > "$runs/$id3/planner.md5"
            else
                failed+=("$id3")
            fi
        done
        ;;
    *) echo "unknown experiment $experiment (mt1-ind, mt10, mt-test, mt20, terl-pipeline)" >&2; exit 2 ;;
esac
if [ ${#failed[@]} -gt 0 ]; then
    say "failed runs (the others finished): ${failed[*]}"
    exit 1
fi
if [ "$experiment" = terl-pipeline ]; then
    say "done; report: $bin/terl report $runs/pipeline-stage1-* $runs/mt10-terl-pipeline-* --out $runs/report-$experiment"
else
    say "done; report: $bin/terl report $runs/$experiment-* --out $runs/report-$experiment"
fi
