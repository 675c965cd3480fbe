"""What the PyTorch references of `terl bench sac` (sac_torch.py) and `terl bench tep`
(tep_torch.py) share: the ReLU MLP, the GEMM FLOP counts as crates/rl counts them, the runner of
an update's bare GEMMs (the denominator of GEMM efficiency) and the square-GEMM rate."""
import time

import torch
import torch.nn as nn


def mlp(sizes, out_act=None):
    """Linear layers of `sizes` with ReLU between them and `out_act` (a module) after the last."""
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    if out_act is not None:
        layers.append(out_act)
    return nn.Sequential(*layers)


def fwd_flops(sizes, rows):
    """GEMM FLOPs of a forward pass of `rows` rows through layers `sizes`."""
    return sum(2 * rows * i * o for i, o in zip(sizes, sizes[1:]))


def bwd_flops(sizes, rows, params, input_cols):
    """GEMM FLOPs of a backward pass: dW of every layer when `params`, dX of every layer but
    the first, whose dX covers only `input_cols` columns (0: none)."""
    f = 0
    for l, (i, o) in enumerate(zip(sizes, sizes[1:])):
        if params:
            f += 2 * rows * i * o
        f += 2 * rows * (input_cols if l == 0 else i) * o
    return f


def gemm_runner(ops):
    """A function running the plan's GEMMs once, and the FLOPs of one run. `ops` are
    (kind, rows, n_in, n_out, cols) tuples, kind "fwd" (X W^T), "dw" (dY^T X) or "dx" (dY W)."""
    bufs = []
    for kind, rows, i, o, cols in ops:
        if kind == "fwd":
            bufs.append((kind, torch.randn(rows, i), torch.randn(o, i), torch.empty(rows, o)))
        elif kind == "dw":
            bufs.append((kind, torch.randn(rows, o), torch.randn(rows, i), torch.empty(o, i)))
        else:
            bufs.append((kind, torch.randn(rows, o), torch.randn(o, i)[:, :cols], torch.empty(rows, cols)))
    flops = sum(2 * rows * cols * o for _, rows, i, o, cols in ops)

    def run():
        for kind, a, w, c in bufs:
            if kind == "fwd":
                torch.mm(a, w.t(), out=c)
            elif kind == "dw":
                torch.mm(a.t(), w, out=c)
            else:
                torch.mm(a, w, out=c)

    return run, flops


def square_gflops(n, seconds):
    """GFLOP/s of an n×n GEMM, run for at least `seconds` (and at least twice)."""
    a, b, c = torch.randn(n, n), torch.randn(n, n), torch.empty(n, n)
    torch.mm(a, b.t(), out=c)
    k, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds or k < 2:
        torch.mm(a, b.t(), out=c)
        k += 1
    return 2 * n**3 * k / (time.perf_counter() - t0) / 1e9
