"""Env steps per second of Python Meta-World 3.1.1 (the reference the Rust tasks are checked
against), one environment on one thread, random actions, reset at the 500-step truncation:
the same loop as `terl bench env`. Prints one JSON object: per task steps/s.

    .deps/metaworld-venv/bin/python deploy/bench/metaworld_python.py --tasks reach-v3,push-v3 --seconds 3
"""
import argparse
import json
import time

import metaworld
import numpy as np

MT10 = ["reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3",
        "drawer-close-v3", "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3",
        "window-close-v3"]


def rate(name: str, seconds: float) -> float:
    mt1 = metaworld.MT1(name, seed=0)
    env = mt1.train_classes[name]()
    env.set_task(mt1.train_tasks[0])
    env.reset()
    rng = np.random.default_rng(0)
    steps, t = 0, 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(100):
            _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
            steps += 1
            t += 1
            if terminated or truncated or t >= env.max_path_length:
                env.reset()
                t = 0
    return steps / (time.perf_counter() - start)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", default=",".join(MT10))
    ap.add_argument("--seconds", type=float, default=3.0)
    a = ap.parse_args()
    tasks = {t: rate(t, a.seconds) for t in a.tasks.split(",")}
    print(json.dumps({"implementation": "python-metaworld-3.1.1",
                      "seconds_per_task": a.seconds,
                      "steps_per_second": tasks,
                      "median_steps_per_second": float(np.median(list(tasks.values())))}))


if __name__ == "__main__":
    main()
