#!/usr/bin/env python3
"""Record Meta-World v3 parity traces (JSON Lines, gzip) from the real Python Meta-World.

Format: /work/shared/formats/metaworld-trace.md (header line, t=0 line after reset, one line per
step). Run inside the venv made by tests/parity/setup-venv.sh:

    .deps/venv/bin/python tests/parity/record_traces.py               # all 50 tasks, seeds 1 2
    .deps/venv/bin/python tests/parity/record_traces.py --tasks reach-v3 --seeds 7 --noise 0.1

Environment: `ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE["<task>-goal-observable"](seed=seed)` (fully
observable, goal in obs[36:39]; the constructor samples the task's rand_vec from the global
NumPy RNG seeded with `seed` and then freezes it), followed by one explicit `env.reset()`.

Policy: `metaworld.policies.ENV_POLICY_MAP[task]()` plus i.i.d. Gaussian noise,
    a = float32(clip(policy(obs) + N(0, noise^2), -1, 1)),
with the noise drawn from `numpy.random.default_rng(seed)` (4 normals per step, in step order).
The float32 action is passed to `env.step` unchanged and written to the trace as the exact float32
value (Python repr of the float64 that equals it), so a replay applies bit-identical actions.

Precision: `rand_vec` and actions are exact; `obs` and `reward` are rounded to 10 significant
digits (`--digits`), far below the 1e-4 / 1e-3 comparison tolerances.

After recording, each trace is replayed (unless --no-verify) in a *fresh* env built with a
different seed whose rand_vec is overwritten by the header's rand_vec, and the replayed
observations/rewards/success flags must be bit-identical: this checks that rand_vec alone
determines the initial state, as the Rust replay assumes.
"""

from __future__ import annotations

import argparse
import gzip
import io
import json
import multiprocessing as mp
import os
import sys
import time
import warnings
from importlib.metadata import version

import numpy as np


def all_tasks() -> list[str]:
    """Every Meta-World v3 task, in Meta-World's order (`ALL_V3_ENVIRONMENTS`): all are ported."""
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS

    return list(ALL_V3_ENVIRONMENTS)


DEFAULT_SEEDS = [1, 2]
DEFAULT_NOISE = 0.1
VERIFY_SEED_OFFSET = 1000


def make_env(task: str, seed: int):
    # The scripted policies warn whenever their P-controller output exceeds [-1, 1].
    warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")
    from metaworld.env_dict import ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE

    key = f"{task}-goal-observable"
    if key not in ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE:
        raise SystemExit(f"unknown Meta-World v3 task: {task}")
    return ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE[key](seed=seed)


def rnd(x: float, digits: int) -> float:
    return float(f"{float(x):.{digits}g}")


def rnd_vec(v, digits: int) -> list[float]:
    return [rnd(x, digits) for x in np.asarray(v, dtype=np.float64)]


def exact_vec(v) -> list[float]:
    # float(np.float32) / float(np.float64) is exact; json writes the shortest repr that
    # round-trips to that float64 (= the exact float32 value for actions).
    return [float(x) for x in np.asarray(v).ravel()]


def mt50_index(task: str) -> int | None:
    from metaworld.env_dict import MT50_V3

    names = list(MT50_V3.keys())
    return names.index(task) if task in names else None


def record(task: str, seed: int, noise: float, digits: int):
    """Returns (header, lines, raw) where raw holds the unrounded data for verification."""
    import mujoco
    from metaworld.policies import ENV_POLICY_MAP

    env = make_env(task, seed)
    obs, _ = env.reset()
    rand_vec = np.array(env._last_rand_vec, dtype=np.float64).copy()
    header = {
        "task": task,
        "rand_vec": [float(x) for x in rand_vec],
        "seed": seed,
        "mt50_index": mt50_index(task),
        "env": f"ALL_V3_ENVIRONMENTS_GOAL_OBSERVABLE['{task}-goal-observable'](seed={seed}); reset()",
        "policy": f"metaworld.policies.ENV_POLICY_MAP['{task}'] + N(0, noise_std^2), clip [-1,1], float32",
        "noise_std": noise,
        "noise_rng": f"numpy.random.default_rng({seed}).normal(0, noise_std, 4) per step",
        "obs_digits": digits,
        "max_path_length": int(env.max_path_length),
        "metaworld_version": version("metaworld"),
        "mujoco_version": mujoco.__version__,
        "numpy_version": np.__version__,
        "target_pos": exact_vec(env._target_pos),
        "obj_init_pos": exact_vec(env.obj_init_pos) if env.obj_init_pos is not None else None,
        "hand_init_pos": exact_vec(env.hand_init_pos),
    }
    policy = ENV_POLICY_MAP[task]()
    rng = np.random.default_rng(seed)
    lines = [{"t": 0, "obs": rnd_vec(obs, digits)}]
    raw = {"obs": [obs.copy()], "actions": [], "rewards": [], "success": []}
    ever, first_success, t = False, None, 0
    truncated = False
    while not truncated:
        a = policy.get_action(obs).astype(np.float64)
        a = np.clip(a + rng.normal(0.0, noise, size=4), -1.0, 1.0).astype(np.float32)
        obs, reward, terminated, truncated, info = env.step(a)
        t += 1
        assert not terminated
        succ = float(info["success"])
        if succ and not ever:
            ever, first_success = True, t
        lines.append({
            "t": t,
            "action": exact_vec(a),
            "obs": rnd_vec(obs, digits),
            "reward": rnd(reward, digits),
            "success": succ,
            "truncated": bool(truncated),
        })
        raw["obs"].append(obs.copy())
        raw["actions"].append(a.copy())
        raw["rewards"].append(float(reward))
        raw["success"].append(succ)
    header["steps"] = t
    header["final_success"] = raw["success"][-1]
    header["ever_success"] = ever
    header["first_success_step"] = first_success
    env.close()
    return header, lines, raw


def verify(task: str, seed: int, rand_vec: np.ndarray, raw) -> str | None:
    """Replays the actions in a fresh env whose frozen rand_vec is overwritten; None if identical."""
    env = make_env(task, seed + VERIFY_SEED_OFFSET)
    env._last_rand_vec = rand_vec.copy()  # _freeze_rand_vec is True after construction
    obs, _ = env.reset()
    if not np.array_equal(obs, raw["obs"][0]):
        return f"reset obs differs (max {np.max(np.abs(obs - raw['obs'][0])):.3g})"
    for i, a in enumerate(raw["actions"]):
        obs, r, _, _, info = env.step(a)
        if not (np.array_equal(obs, raw["obs"][i + 1]) and r == raw["rewards"][i]
                and float(info["success"]) == raw["success"][i]):
            return f"step {i + 1} differs (obs max {np.max(np.abs(obs - raw['obs'][i + 1])):.3g})"
    env.close()
    return None


def write_trace(path: str, header, lines) -> None:
    buf = io.BytesIO()
    # mtime=0 and no file name: byte-identical output for identical traces.
    with gzip.GzipFile(filename="", mode="wb", fileobj=buf, mtime=0, compresslevel=9) as gz:
        for obj in [header, *lines]:
            gz.write((json.dumps(obj, separators=(",", ":"), allow_nan=False) + "\n").encode())
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(buf.getvalue())
    os.replace(tmp, path)


def job(args):
    task, seed, noise, digits, out_dir, do_verify = args
    t0 = time.time()
    header, lines, raw = record(task, seed, noise, digits)
    problem = verify(task, seed, np.array(header["rand_vec"]), raw) if do_verify else None
    path = os.path.join(out_dir, f"{task}-s{seed}.jsonl.gz")
    write_trace(path, header, lines)
    return {
        "task": task, "seed": seed, "path": path, "bytes": os.path.getsize(path),
        "ever_success": header["ever_success"], "first_success_step": header["first_success_step"],
        "final_success": header["final_success"], "verify": problem, "secs": time.time() - t0,
    }


def main() -> int:
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=None, help="Meta-World v3 task names (default: all 50)")
    p.add_argument("--seeds", nargs="+", type=int, default=DEFAULT_SEEDS, help="env/noise seeds (default: 1 2)")
    p.add_argument("--out-dir", default=os.path.join(root, "tests", "fixtures", "metaworld"))
    p.add_argument("--noise", type=float, default=DEFAULT_NOISE, help="Gaussian action noise std (default 0.1)")
    p.add_argument("--digits", type=int, default=10, help="significant digits for obs and reward (default 10)")
    p.add_argument("--jobs", type=int, default=min(8, os.cpu_count() or 1))
    p.add_argument("--no-verify", action="store_true", help="skip the bit-exact replay check")
    a = p.parse_args()
    tasks = [t.strip() for ts in (a.tasks or all_tasks()) for t in ts.split(",") if t.strip()]
    os.makedirs(a.out_dir, exist_ok=True)
    jobs = [(t, s, a.noise, a.digits, a.out_dir, not a.no_verify) for t in tasks for s in a.seeds]
    with mp.get_context("spawn").Pool(max(1, a.jobs)) as pool:
        results = pool.map(job, jobs)
    total, bad = 0, 0
    for r in results:
        total += r["bytes"]
        status = "SUCCESS" if r["ever_success"] else "no success"
        first = f" first at step {r['first_success_step']}" if r["ever_success"] else ""
        ver = "" if a.no_verify else (" replay=ok" if r["verify"] is None else f" replay=FAIL ({r['verify']})")
        bad += r["verify"] is not None
        print(f"{r['task']:<26} seed {r['seed']:<3} {status}{first}, final={r['final_success']:.0f}"
              f"{ver}  {r['bytes'] / 1024:.0f} KiB  {r['secs']:.1f}s")
    n_ok = sum(r["ever_success"] for r in results)
    print(f"{n_ok}/{len(results)} traces reached success; {len(results)} files, "
          f"{total / 1024 / 1024:.2f} MiB in {a.out_dir}")
    if bad:
        print(f"ERROR: {bad} trace(s) did not replay bit-identically", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
