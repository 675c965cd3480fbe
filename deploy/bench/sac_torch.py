#!/usr/bin/env python3
"""PyTorch CPU reference of terl's MTSAC update, for `terl bench sac` comparisons.

Same networks (ReLU MLPs; policy outputs [mean | log_std], critics take obs+one-hot+action),
same losses and the same update order as crates/rl/src/sac.rs: all losses from the parameters
at the start of the update, then Adam steps and Polyak targets (tau 0.005). Prints one JSON
object with the same fields as the Rust benchmark.

    python3 deploy/bench/sac_torch.py --hidden 400 --layers 3 --batch 1280 --threads 2 --seconds 5

Needs torch (CPU is enough). FLOPs are counted exactly as the Rust benchmark counts them (the
GEMMs the algorithm needs), so `achieved_gflops` compares like for like.
"""
import argparse
import json
import math
import time

import torch
import torch.nn.functional as F

from torch_common import bwd_flops, fwd_flops, gemm_runner, mlp, square_gflops

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0


class MTSAC:
    def __init__(self, obs_dim, act_dim, num_tasks, hidden, lr=3e-4, gamma=0.99, tau=0.005):
        self.obs_dim, self.act_dim, self.num_tasks = obs_dim, act_dim, num_tasks
        self.gamma, self.tau = gamma, tau
        self.target_entropy = -float(act_dim)
        pin = obs_dim + num_tasks
        self.policy = mlp([pin, *hidden, 2 * act_dim])
        self.q1 = mlp([pin + act_dim, *hidden, 1])
        self.q2 = mlp([pin + act_dim, *hidden, 1])
        self.q1_t = mlp([pin + act_dim, *hidden, 1])
        self.q2_t = mlp([pin + act_dim, *hidden, 1])
        self.q1_t.load_state_dict(self.q1.state_dict())
        self.q2_t.load_state_dict(self.q2.state_dict())
        for p in list(self.q1_t.parameters()) + list(self.q2_t.parameters()):
            p.requires_grad_(False)
        self.log_alpha = torch.zeros(num_tasks, requires_grad=True)
        self.critic_params = list(self.q1.parameters()) + list(self.q2.parameters())
        self.target_params = list(self.q1_t.parameters()) + list(self.q2_t.parameters())
        self.policy_params = list(self.policy.parameters())
        self.pi_opt = torch.optim.Adam(self.policy_params, lr=lr, foreach=True)
        self.q_opt = torch.optim.Adam(self.critic_params, lr=lr, foreach=True)
        self.a_opt = torch.optim.Adam([self.log_alpha], lr=lr, foreach=True)

    def sample(self, x):
        mean, log_std = self.policy(x).chunk(2, dim=-1)
        log_std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        eps = torch.randn_like(mean)
        u = mean + log_std.exp() * eps
        a = torch.tanh(u)
        normal = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        corr = (2.0 * (math.log(2.0) - u - F.softplus(-2.0 * u))).sum(-1)
        return a, normal - corr

    def update(self, obs, act, rew, next_obs, term, task):
        onehot = F.one_hot(task, self.num_tasks).to(obs.dtype)
        s = torch.cat([obs, onehot], -1)
        s2 = torch.cat([next_obs, onehot], -1)
        alpha = self.log_alpha.detach().exp()[task]
        with torch.no_grad():
            a2, logp2 = self.sample(s2)
            x2 = torch.cat([s2, a2], -1)
            q_next = torch.min(self.q1_t(x2), self.q2_t(x2)).squeeze(-1) - alpha * logp2
            y = rew + self.gamma * (1.0 - term) * q_next
        x = torch.cat([s, act], -1)
        qf1_loss = F.mse_loss(self.q1(x).squeeze(-1), y)
        qf2_loss = F.mse_loss(self.q2(x).squeeze(-1), y)
        a_new, logp = self.sample(s)
        xn = torch.cat([s, a_new], -1)
        q_new = torch.min(self.q1(xn), self.q2(xn)).squeeze(-1)
        actor_loss = (alpha * logp - q_new).mean()
        alpha_loss = (-self.log_alpha[task] * (logp.detach() + self.target_entropy)).mean()
        q_grads = torch.autograd.grad(qf1_loss + qf2_loss, self.critic_params)
        pi_grads = torch.autograd.grad(actor_loss, self.policy_params)
        a_grad = torch.autograd.grad(alpha_loss, [self.log_alpha])
        for p, g in zip(self.critic_params, q_grads):
            p.grad = g
        for p, g in zip(self.policy_params, pi_grads):
            p.grad = g
        self.log_alpha.grad = a_grad[0]
        self.q_opt.step()
        self.pi_opt.step()
        self.a_opt.step()
        with torch.no_grad():
            torch._foreach_lerp_(self.target_params, self.critic_params, self.tau)
        return qf1_loss.item()


def layer_sizes(inp, hidden, out):
    return [inp, *hidden, out]


def update_flops(pin, act_dim, hidden, b):
    """GEMM FLOPs of one update, counted as crates/rl's Sac::update_flops counts them."""
    p = layer_sizes(pin, hidden, 2 * act_dim)
    q = layer_sizes(pin + act_dim, hidden, 1)
    policy = fwd_flops(p, 2 * b) + bwd_flops(p, b, True, 0)
    critic = (
        fwd_flops(q, b) + fwd_flops(q, 2 * b) + bwd_flops(q, b, True, 0) + bwd_flops(q, b, False, act_dim)
    )
    return policy + 2 * critic


def gemm_plan(pin, act_dim, hidden, b):
    """The same GEMM shapes as the update, as (kind, rows, n_in, n_out, cols) tuples."""
    ops = []
    p = layer_sizes(pin, hidden, 2 * act_dim)
    q = layer_sizes(pin + act_dim, hidden, 1)
    for i, o in zip(p, p[1:]):
        ops.append(("fwd", 2 * b, i, o, i))
    for l, (i, o) in reversed(list(enumerate(zip(p, p[1:])))):
        ops.append(("dw", b, i, o, i))
        if l > 0:
            ops.append(("dx", b, i, o, i))
    for _ in range(2):
        for rows in (b, 2 * b):
            for i, o in zip(q, q[1:]):
                ops.append(("fwd", rows, i, o, i))
        for l, (i, o) in reversed(list(enumerate(zip(q, q[1:])))):
            ops.append(("dw", b, i, o, i))
            if l > 0:
                ops.append(("dx", b, i, o, i))
        for l, (i, o) in reversed(list(enumerate(zip(q, q[1:])))):
            ops.append(("dx", b, i, o, i if l > 0 else act_dim))
    return ops


def time_gemms(ops, seconds):
    """GFLOP/s of the plan's bare GEMMs, run for at least `seconds` (and at least three times)."""
    run, flops = gemm_runner(ops)
    run()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or n < 3:
        run()
        n += 1
    return flops * n / (time.perf_counter() - t0) / 1e9


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--obs-dim", type=int, default=49, help="policy input: observation + one-hot task id")
    ap.add_argument("--act-dim", type=int, default=4)
    ap.add_argument("--hidden", type=int, default=400)
    ap.add_argument("--layers", type=int, default=3)
    ap.add_argument("--batch", type=int, default=1280)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--num-tasks", type=int, default=10)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    obs_dim = args.obs_dim - args.num_tasks
    hidden = [args.hidden] * args.layers
    b = args.batch
    sac = MTSAC(obs_dim, args.act_dim, args.num_tasks, hidden)
    obs = torch.rand(b, obs_dim) * 2 - 1
    next_obs = torch.rand(b, obs_dim) * 2 - 1
    act = torch.rand(b, args.act_dim) * 2 - 1
    rew = torch.rand(b)
    term = torch.zeros(b)
    task = torch.arange(b) % args.num_tasks

    for _ in range(2):
        sac.update(obs, act, rew, next_obs, term, task)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < args.seconds or n < 3:
        sac.update(obs, act, rew, next_obs, term, task)
        n += 1
    elapsed = time.perf_counter() - t0
    pin = obs_dim + args.num_tasks
    flops = update_flops(pin, args.act_dim, hidden, b)
    ups = n / elapsed
    achieved = flops * ups / 1e9
    gemm = time_gemms(gemm_plan(pin, args.act_dim, hidden, b), min(max(args.seconds / 3, 0.3), 3.0))
    square = square_gflops(1024, min(max(args.seconds / 10, 0.2), 1.0))

    # Actor path: one thread, batch 8, stochastic action, no autograd.
    torch.set_num_threads(1)
    x8 = torch.rand(8, obs_dim) * 2 - 1
    t8 = torch.arange(8) % args.num_tasks
    with torch.inference_mode():
        def act8():
            s = torch.cat([x8, F.one_hot(t8, args.num_tasks).to(x8.dtype)], -1)
            return sac.sample(s)[0]

        for _ in range(20):
            act8()
        k, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < min(max(args.seconds / 10, 0.2), 1.0):
            act8()
            k += 1
        infer_us = (time.perf_counter() - t0) * 1e6 / k

    report = {
        "implementation": f"pytorch-{torch.__version__}-cpu",
        "instruction_set": torch.backends.cpu.get_cpu_capability().lower(),
        "config": {
            "obs_dim": args.obs_dim,
            "act_dim": args.act_dim,
            "hidden": args.hidden,
            "layers": args.layers,
            "batch": b,
            "threads": args.threads,
            "seconds": args.seconds,
            "num_tasks": args.num_tasks,
        },
        "updates": n,
        "updates_per_s": ups,
        "update_ms": 1e3 / ups,
        "flops_per_update": flops,
        "achieved_gflops": achieved,
        "gemm_gflops": gemm,
        "gemm_efficiency": achieved / gemm,
        "gemm_square_gflops": square,
        "inference_batch8_us": infer_us,
    }
    print(json.dumps(report))


if __name__ == "__main__":
    main()
