#!/usr/bin/env python3
"""Side-by-side table of compare_sac.sh output: median per config, Rust/PyTorch ratios."""
import json
import statistics
import sys
from collections import defaultdict

runs = defaultdict(lambda: defaultdict(list))
for line in sys.stdin:
    line = line.strip()
    if not line.startswith("{"):
        continue
    r = json.loads(line)
    c = r["config"]
    key = (c["layers"], c["hidden"], c["batch"], c["threads"])
    impl = "rust" if r["implementation"].startswith("terl") else "torch"
    runs[key][impl].append(r)


def med(rs, field):
    return statistics.median(x[field] for x in rs) if rs else float("nan")


print("| net | batch | threads | Rust upd/s | PyTorch upd/s | ratio | Rust GFLOP/s (GEMM-rate, eff) | PyTorch GFLOP/s (GEMM-rate, eff) | infer b8 µs Rust / PyTorch |")
print("|---|---|---|---|---|---|---|---|---|")
for key in sorted(runs, key=lambda k: (-k[2], -k[1], k[3])):
    layers, hidden, batch, threads = key
    rs, ts = runs[key]["rust"], runs[key]["torch"]
    ru, tu = med(rs, "updates_per_s"), med(ts, "updates_per_s")
    print(
        f"| {layers}x{hidden} | {batch} | {threads} | {ru:.2f} | {tu:.2f} | {ru / tu:.2f}x "
        f"| {med(rs, 'achieved_gflops'):.1f} ({med(rs, 'gemm_gflops'):.1f}, {med(rs, 'gemm_efficiency'):.0%}) "
        f"| {med(ts, 'achieved_gflops'):.1f} ({med(ts, 'gemm_gflops'):.1f}, {med(ts, 'gemm_efficiency'):.0%}) "
        f"| {med(rs, 'inference_batch8_us'):.0f} / {med(ts, 'inference_batch8_us'):.0f} |"
    )
