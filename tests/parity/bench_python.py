#!/usr/bin/env python3
"""Python Meta-World env throughput, for comparison with the Rust port.

For each MT10 task: one goal-observable env (seeded), single thread, uniform random actions in
[-1, 1]^4 (float32), `reset()` whenever the episode is truncated (every 500 steps). Reports env
steps per second with the reset time included (`steps_per_sec`) and excluded
(`steps_per_sec_excl_reset`), and the mean reset time. Prints JSON to stdout.

    .deps/venv/bin/python tests/parity/bench_python.py [--steps 5000] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

# Keep BLAS single-threaded so the number is a true single-thread figure.
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

MT10 = [
    "reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3", "drawer-close-v3",
    "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3", "window-close-v3",
]


def bench(task: str, steps: int, seed: int) -> dict:
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE

    env = ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE[f"{task}-goal-observable"](seed=seed)
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1.0, 1.0, size=(steps, 4)).astype(np.float32)
    env.reset()
    resets, reset_secs = 0, 0.0
    t0 = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            r0 = time.perf_counter()
            env.reset()
            reset_secs += time.perf_counter() - r0
            resets += 1
    dt = time.perf_counter() - t0
    env.close()
    return {
        "steps": steps,
        "resets": resets,
        "seconds": round(dt, 4),
        "steps_per_sec": round(steps / dt, 1),
        "reset_ms": round(1000 * reset_secs / max(resets, 1), 2),
        "steps_per_sec_excl_reset": round(steps / (dt - reset_secs), 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=5000, help="env steps per task (default 5000 = 10 episodes)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--tasks", nargs="+", default=MT10)
    a = p.parse_args()

    import mujoco
    from importlib.metadata import version

    per_task = {t: bench(t, a.steps, a.seed) for t in a.tasks}
    total_steps = sum(r["steps"] for r in per_task.values())
    total_secs = sum(r["seconds"] for r in per_task.values())
    out = {
        "benchmark": "python-metaworld-env-steps",
        "threads": 1,
        "policy": "uniform random float32 actions, reset at truncation (500 steps)",
        "metaworld_version": version("metaworld"),
        "mujoco_version": mujoco.__version__,
        "numpy_version": np.__version__,
        "python": platform.python_version(),
        "cpu": platform.processor() or platform.machine(),
        "tasks": per_task,
        "overall_steps_per_sec": round(total_steps / total_secs, 1),
    }
    json.dump(out, sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
