"""The reference path of the terl-stats test: rliable's own estimates on the same scores.

Reads JSON from stdin: {"x": [[...], ...], "y": [[...], ...], "reps": N, "poi_reps": M, "seed": S} (runs x tasks
matrices) and prints JSON with, for x and y, rliable's aggregate_mean and aggregate_iqm and their
95 % stratified percentile-bootstrap intervals (library.get_interval_estimates), and the
probability of improvement of x over y (metrics.probability_of_improvement) with its interval
(StratifiedIndependentBootstrap, as rliable's plot_utils use it).
"""
import json
import sys

import numpy as np
from rliable import library, metrics


def main():
    req = json.load(sys.stdin)
    x = np.array(req["x"], dtype=np.float64)
    y = np.array(req["y"], dtype=np.float64)
    reps = int(req["reps"])
    # rliable resamples with numpy's global RNG.
    np.random.seed(int(req.get("seed", 0)))
    both = lambda s: np.array([metrics.aggregate_mean(s), metrics.aggregate_iqm(s)])
    points, cis = library.get_interval_estimates({"x": x, "y": y}, both, reps=reps)
    out = {}
    for key in ("x", "y"):
        out[key] = {
            "mean": float(points[key][0]),
            "mean_ci": [float(cis[key][0][0]), float(cis[key][1][0])],
            "iqm": float(points[key][1]),
            "iqm_ci": [float(cis[key][0][1]), float(cis[key][1][1])],
        }
    poi = lambda a, b: np.array([metrics.probability_of_improvement(a, b)])
    p_points, p_cis = library.get_interval_estimates(
        {"x,y": (x, y)}, poi, reps=int(req.get("poi_reps", reps))
    )
    out["poi"] = float(p_points["x,y"][0])
    out["poi_ci"] = [float(p_cis["x,y"][0][0]), float(p_cis["x,y"][1][0])]
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
