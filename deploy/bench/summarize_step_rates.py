#!/usr/bin/env python3
"""Medians over rounds of step_rates.sh's reports: per task env steps/s of terl, Python
Meta-World and EnvPool (1 and 32 environments per call, one worker thread) and terl's ratio to
each; writes <dir>/env-step-rates.json and prints a Markdown table.

    python3 deploy/bench/summarize_step_rates.py docs/results/scaling 2 2
"""
import json
import statistics
import sys

if len(sys.argv) != 4 or not sys.argv[2].isdigit() or int(sys.argv[2]) < 1:
    sys.exit("usage: summarize_step_rates.py DIR ROUNDS SECONDS (ROUNDS >= 1; step_rates.sh calls it)")
out, rounds, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])


def load(prefix):
    """Per task, the list of env steps/s over rounds."""
    per_task = {}
    for k in range(1, rounds + 1):
        with open(f"{out}/{prefix}-round{k}.json") as f:
            report = json.load(f)
        if "tasks" in report:  # terl bench env
            rates = {t["task"]: t["env_steps_per_s"] for t in report["tasks"]}
        else:
            rates = report["steps_per_second"]
        for task, r in rates.items():
            per_task.setdefault(task, []).append(r)
    return per_task


terl = load("terl-bench-env")
python = load("python-metaworld")
ep1 = load("envpool-1")
ep32 = load("envpool-32")
rows = []
for task in terl:
    t, p, e1, e32 = (statistics.median(d[task]) for d in (terl, python, ep1, ep32))
    rows.append({
        "task": task,
        "terl_env_steps_per_s": round(t, 1),
        "python_metaworld_env_steps_per_s": round(p, 1),
        "envpool_1_env_steps_per_s": round(e1, 1),
        "envpool_32_env_steps_per_s": round(e32, 1),
        "terl_over_python": round(t / p, 2),
        "terl_over_envpool_1": round(t / e1, 2),
        "terl_over_envpool_32": round(t / e32, 2),
    })
summary = {"rounds": rounds, "seconds_per_task": seconds, "tasks": rows}
for key in ("terl_over_python", "terl_over_envpool_1", "terl_over_envpool_32"):
    summary[f"median_{key}"] = round(statistics.median(r[key] for r in rows), 2)
with open(f"{out}/env-step-rates.json", "w") as f:
    json.dump(summary, f, indent=1)
    f.write("\n")
print("| task | terl | Python Meta-World | EnvPool, 1 env per call | EnvPool, 32 envs per call "
      "| terl / Python | terl / EnvPool 1 | terl / EnvPool 32 |")
print("|---|---|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['task']} | {r['terl_env_steps_per_s']:,.0f} | "
          f"{r['python_metaworld_env_steps_per_s']:,.0f} | {r['envpool_1_env_steps_per_s']:,.0f} | "
          f"{r['envpool_32_env_steps_per_s']:,.0f} | {r['terl_over_python']:.2f} | "
          f"{r['terl_over_envpool_1']:.2f} | {r['terl_over_envpool_32']:.2f} |")
print(f"| **median** | | | | | **{summary['median_terl_over_python']:.2f}** | "
      f"**{summary['median_terl_over_envpool_1']:.2f}** | **{summary['median_terl_over_envpool_32']:.2f}** |")
