#!/usr/bin/env python3
"""PyTorch CPU reference of terl's TEP update, for `terl bench tep` comparisons.

Same networks as crates/rl/src/tep.rs (F: [s, s', a] -> hidden^layers ReLU -> 1 linear; AN:
[s, s'] -> hidden^layers ReLU -> act tanh), same losses, all from the parameters at the start
of the update:

    F loss  = mean[(F(s,s1,a) - 1)^2 + (F(s,g,a) - z)^2 + (F(s,s1,a) - F(s1,s,-a))^2],
              z = 1 + F_target(s1, g, AN_target(s1, g))   (no gradient)
    AN loss = mean F(s, g, AN(s, g))   (F frozen: only AN's parameters get its gradient)

then Adam (lr 3e-4) on both and Polyak targets (tau 0.005). Prints one JSON object with the same
fields as the Rust benchmark.

    python3 deploy/bench/tep_torch.py --batch 1024 --threads 2 --seconds 5

Needs torch (CPU is enough). FLOPs are counted exactly as the Rust benchmark counts them (the
GEMMs the algorithm needs), so `achieved_gflops` compares like for like.
"""
import argparse
import json
import time

import torch
import torch.nn as nn

from torch_common import bwd_flops, fwd_flops, gemm_runner, mlp, square_gflops


class TEP:
    def __init__(self, obs_dim, act_dim, hidden, lr=3e-4, tau=0.005):
        self.tau = tau
        self.f = mlp([2 * obs_dim + act_dim, *hidden, 1])
        self.an = mlp([2 * obs_dim, *hidden, act_dim], nn.Tanh())
        self.f_t = mlp([2 * obs_dim + act_dim, *hidden, 1])
        self.an_t = mlp([2 * obs_dim, *hidden, act_dim], nn.Tanh())
        self.f_t.load_state_dict(self.f.state_dict())
        self.an_t.load_state_dict(self.an.state_dict())
        self.f_params = list(self.f.parameters())
        self.an_params = list(self.an.parameters())
        self.target_params = list(self.f_t.parameters()) + list(self.an_t.parameters())
        self.source_params = self.f_params + self.an_params
        for p in self.target_params:
            p.requires_grad_(False)
        self.f_opt = torch.optim.Adam(self.f_params, lr=lr, foreach=True)
        self.an_opt = torch.optim.Adam(self.an_params, lr=lr, foreach=True)

    def update(self, s, a, s1, g):
        with torch.no_grad():
            ta = self.an_t(torch.cat([s1, g], -1))
            z = 1.0 + self.f_t(torch.cat([s1, g, ta], -1)).squeeze(-1)
        b = s.shape[0]
        # The three F-loss evaluations share one forward pass (as the Rust update stacks them).
        x = torch.cat(
            [
                torch.cat([s, s1, a], -1),
                torch.cat([s, g, a], -1),
                torch.cat([s1, s, -a], -1),
            ]
        )
        y = self.f(x).squeeze(-1)
        y1, y2, y3 = y[:b], y[b : 2 * b], y[2 * b :]
        f_loss = ((y1 - 1.0).pow(2) + (y2 - z).pow(2) + (y1 - y3).pow(2)).mean()
        an_a = self.an(torch.cat([s, g], -1))
        an_loss = self.f(torch.cat([s, g, an_a], -1)).mean()
        f_grads = torch.autograd.grad(f_loss, self.f_params)
        # Only AN's parameters: F's parameters get nothing from the AN loss.
        an_grads = torch.autograd.grad(an_loss, self.an_params)
        for p, gr in zip(self.f_params, f_grads):
            p.grad = gr
        for p, gr in zip(self.an_params, an_grads):
            p.grad = gr
        self.f_opt.step()
        self.an_opt.step()
        with torch.no_grad():
            torch._foreach_lerp_(self.target_params, self.source_params, self.tau)
        return f_loss.item()


def update_flops(obs_dim, act_dim, hidden, b):
    """GEMM FLOPs of one update, counted as crates/rl's Tep::update_flops counts them."""
    fs = [2 * obs_dim + act_dim, *hidden, 1]
    ans = [2 * obs_dim, *hidden, act_dim]
    return (
        2 * fwd_flops(ans, b)
        + fwd_flops(fs, b)
        + fwd_flops(fs, 4 * b)
        + bwd_flops(fs, 3 * b, True, 0)
        + bwd_flops(fs, b, False, act_dim)
        + bwd_flops(ans, b, True, 0)
    )


def gemm_plan(obs_dim, act_dim, hidden, b):
    """The same GEMM shapes as the update, as (kind, rows, n_in, n_out, cols) tuples."""
    fs = [2 * obs_dim + act_dim, *hidden, 1]
    ans = [2 * obs_dim, *hidden, act_dim]
    ops = []

    def forward(sizes, rows):
        for i, o in zip(sizes, sizes[1:]):
            ops.append(("fwd", rows, i, o, i))

    def backward(sizes, rows, params, first_cols):
        for l, (i, o) in reversed(list(enumerate(zip(sizes, sizes[1:])))):
            if params:
                ops.append(("dw", rows, i, o, i))
            cols = i if l > 0 else first_cols
            if cols > 0:
                ops.append(("dx", rows, i, o, cols))

    forward(ans, b)
    forward(fs, b)
    forward(ans, b)
    forward(fs, 4 * b)
    backward(fs, 3 * b, True, 0)
    backward(fs, b, False, act_dim)
    backward(ans, b, True, 0)
    return ops


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--obs-dim", type=int, default=39)
    ap.add_argument("--act-dim", type=int, default=4)
    ap.add_argument("--hidden", type=int, default=512)
    ap.add_argument("--layers", type=int, default=3)
    ap.add_argument("--batch", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    od, ad, b = args.obs_dim, args.act_dim, args.batch
    hidden = [args.hidden] * args.layers
    tep = TEP(od, ad, hidden)
    s = torch.rand(b, od) * 2 - 1
    a = torch.rand(b, ad) * 2 - 1
    s1 = torch.rand(b, od) * 2 - 1
    g = torch.rand(b, od) * 2 - 1

    for _ in range(2):
        tep.update(s, a, s1, g)
    # Updates and bare GEMMs alternate in short slices, as the Rust benchmark does.
    run_gemms, plan_flops = gemm_runner(gemm_plan(od, ad, hidden, b))
    flops = update_flops(od, ad, hidden, b)
    assert plan_flops == flops, "the GEMM plan must mirror the update"
    run_gemms()
    slice_s = min(max(args.seconds / 10, 0.05), 0.5)
    n, upd_s, gemm_s, gemm_runs = 0, 0.0, 0.0, 0
    while upd_s < args.seconds or n < 3:
        t0 = time.perf_counter()
        while True:
            tep.update(s, a, s1, g)
            n += 1
            if time.perf_counter() - t0 >= slice_s:
                break
        upd_s += time.perf_counter() - t0
        t0 = time.perf_counter()
        while True:
            run_gemms()
            gemm_runs += 1
            if time.perf_counter() - t0 >= slice_s / 2:
                break
        gemm_s += time.perf_counter() - t0
    ups = n / upd_s
    achieved = flops * ups / 1e9
    gemm = flops * gemm_runs / gemm_s / 1e9
    square = square_gflops(1024, min(max(args.seconds / 10, 0.2), 1.0))

    # Actor path: one thread, batch 8, F on (s, g, a) and AN on (s, g), no autograd.
    torch.set_num_threads(1)
    x8 = torch.rand(8, 2 * od + ad) * 2 - 1
    with torch.inference_mode():
        def plan8():
            return tep.f(x8), tep.an(x8[:, : 2 * od])

        for _ in range(20):
            plan8()
        k, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < min(max(args.seconds / 10, 0.2), 1.0):
            plan8()
            k += 1
        plan_us = (time.perf_counter() - t0) * 1e6 / k

    report = {
        "implementation": f"pytorch-{torch.__version__}-cpu",
        "instruction_set": torch.backends.cpu.get_cpu_capability().lower(),
        "config": {
            "obs_dim": od,
            "act_dim": ad,
            "hidden": args.hidden,
            "layers": args.layers,
            "batch": b,
            "threads": args.threads,
            "seconds": args.seconds,
        },
        "updates": n,
        "updates_per_s": ups,
        "update_ms": 1e3 / ups,
        "flops_per_update": flops,
        "achieved_gflops": achieved,
        "gemm_gflops": gemm,
        "gemm_efficiency": achieved / gemm,
        "gemm_square_gflops": square,
        "planner_batch8_us": plan_us,
    }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
