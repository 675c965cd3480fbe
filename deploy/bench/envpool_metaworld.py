"""Env steps per second of EnvPool 1.2.5's native C++ Meta-World v3 (`MetaWorld/<Task>-v3`),
on one worker thread: `--envs 1` is the loop of `terl bench env` and metaworld_python.py (one
environment, random actions, reset at the 500-step truncation: EnvPool resets by itself); with
`--envs N` one call steps N environments in C++ on that thread, so the Python overhead per
call is shared N ways and the figure approaches EnvPool's per-core physics rate. Every step
call counts (EnvPool's reset after a truncation is one of its step calls, 1 in 501). Prints one
JSON object: per task env steps/s (all N environments together).

    .deps/envpool-venv/bin/python deploy/bench/envpool_metaworld.py --tasks reach-v3 --envs 8 --seconds 3
"""
import argparse
import json
import math
import time

import envpool
import numpy as np

MT10 = ["reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3",
        "drawer-close-v3", "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3",
        "window-close-v3"]


def task_id(name: str) -> str:
    """`pick-place-v3` -> `MetaWorld/PickPlace-v3` (EnvPool's registration)."""
    base, version = name.rsplit("-", 1)
    return "MetaWorld/" + "".join(p[:1].upper() + p[1:] for p in base.split("-")) + "-" + version


def rate(name: str, envs: int, seconds: float) -> float:
    env = envpool.make(task_id(name), env_type="gymnasium", num_envs=envs, batch_size=envs,
                       num_threads=1, seed=0)
    env.reset()
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, (envs, 4)).astype(np.float32) for _ in range(100)]
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for a in actions:
            env.step(a)
        steps += 100 * envs
    elapsed = time.perf_counter() - start
    env.close()
    return steps / elapsed


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default=",".join(MT10))
    ap.add_argument("--envs", type=int, default=1, help="environments stepped per call, on one thread")
    ap.add_argument("--seconds", type=float, default=3.0)
    a = ap.parse_args()
    if a.envs < 1 or a.envs > 256:
        ap.error("--envs must be 1..256")
    if not (math.isfinite(a.seconds) and 0.1 <= a.seconds <= 60):
        ap.error("--seconds must be 0.1..60")
    names = a.tasks.split(",")
    known = set(envpool.list_all_envs())
    unknown = [t for t in names if "-" not in t or task_id(t) not in known]
    if unknown:
        ap.error(f"not Meta-World v3 tasks of EnvPool: {', '.join(map(repr, unknown))}")
    tasks = {t: rate(t, a.envs, a.seconds) for t in names}
    print(json.dumps({"implementation": f"envpool-{envpool.__version__}-metaworld",
                      "envs": a.envs,
                      "worker_threads": 1,
                      "seconds_per_task": a.seconds,
                      "steps_per_second": tasks,
                      "median_steps_per_second": float(np.median(list(tasks.values())))}))


if __name__ == "__main__":
    main()
