#!/usr/bin/env python3
"""Side-by-side table of compare_tep.sh output: median per config, Rust/PyTorch ratio.

`ratio` is the median over rounds of each Rust run's updates/s over the PyTorch run right after
it (the two saw about the same background load); `of medians` divides the medians instead; `rounds` lists every round's ratio."""
import statistics
import sys

from bench_runs import isa, med, read_runs, update_ratios

FLOOR = 1.0  # Rust must reach this multiple of PyTorch's updates/s with the same threads.

runs = read_runs(sys.stdin)

print("| net | batch | threads | runs | Rust upd/s | PyTorch upd/s | ratio (rounds; of medians) | floor 1.0x | ISA Rust / PyTorch | Rust GFLOP/s (GEMM-rate, eff) | PyTorch GFLOP/s (GEMM-rate, eff) | planner b8 µs Rust / PyTorch |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for key in sorted(runs, key=lambda k: (-k[2], -k[1], k[3])):
    layers, hidden, batch, threads = key
    rs, ts = runs[key]["rust"], runs[key]["torch"]
    ru, tu = med(rs, "updates_per_s"), med(ts, "updates_per_s")
    pairs = update_ratios(rs, ts)
    ratio = statistics.median(pairs) if pairs else float("nan")
    print(
        f"| {layers}x{hidden} | {batch} | {threads} | {len(rs)}/{len(ts)} | {ru:.3f} | {tu:.3f} "
        f"| {ratio:.2f}x (rounds {' '.join(f'{p:.2f}' for p in pairs)}; {ru / tu if tu > 0 else float('nan'):.2f}x) "
        f"| {('met' if ratio >= FLOOR else 'NOT met') if pairs else 'no PyTorch pair'} "
        f"| {isa(rs)} / {isa(ts)} "
        f"| {med(rs, 'achieved_gflops'):.1f} ({med(rs, 'gemm_gflops'):.1f}, {med(rs, 'gemm_efficiency'):.0%}) "
        f"| {med(ts, 'achieved_gflops'):.1f} ({med(ts, 'gemm_gflops'):.1f}, {med(ts, 'gemm_efficiency'):.0%}) "
        f"| {med(rs, 'planner_batch8_us'):.0f} / {med(ts, 'planner_batch8_us'):.0f} |"
    )
