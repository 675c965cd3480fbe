#!/usr/bin/env python3
"""Side-by-side table of compare_tep.sh output: median per config, Rust/PyTorch ratio.

`ratio` is the median over rounds of each Rust run's updates/s over the PyTorch run right after
it (the two saw about the same background load); `of medians` divides the medians instead; `rounds` lists every round's ratio."""
import json
import statistics
import sys
from collections import defaultdict

FLOOR = 1.0  # Rust must reach this multiple of PyTorch's updates/s with the same threads.

runs = defaultdict(lambda: defaultdict(list))
for line in sys.stdin:
    line = line.strip()
    if not line.startswith("{"):
        continue
    try:
        r = json.loads(line)
        c = r["config"]
        key = tuple(int(c[k]) for k in ("layers", "hidden", "batch", "threads"))
        impl = "rust" if r["implementation"].startswith("terl") else "torch"
        if not float(r["updates_per_s"]) > 0:
            raise ValueError(f"updates_per_s {r['updates_per_s']!r} is not positive")
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        print(f"skipped a malformed line ({e!r}): {line[:80]}", file=sys.stderr)
        continue
    runs[key][impl].append(r)


def med(rs, field):
    """Median of a numeric field over runs (NaN when none has it)."""
    xs = []
    for x in rs:
        try:
            xs.append(float(x[field]))
        except (KeyError, TypeError, ValueError):
            pass
    return statistics.median(xs) if xs else float("nan")


print("| net | batch | threads | runs | Rust upd/s | PyTorch upd/s | ratio (rounds; of medians) | floor 1.0x | ISA Rust / PyTorch | Rust GFLOP/s (GEMM-rate, eff) | PyTorch GFLOP/s (GEMM-rate, eff) | planner b8 µs Rust / PyTorch |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for key in sorted(runs, key=lambda k: (-k[2], -k[1], k[3])):
    layers, hidden, batch, threads = key
    rs, ts = runs[key]["rust"], runs[key]["torch"]
    ru, tu = med(rs, "updates_per_s"), med(ts, "updates_per_s")
    pairs = [float(r["updates_per_s"]) / float(t["updates_per_s"]) for r, t in zip(rs, ts)]
    ratio = statistics.median(pairs) if pairs else float("nan")
    print(
        f"| {layers}x{hidden} | {batch} | {threads} | {len(rs)}/{len(ts)} | {ru:.3f} | {tu:.3f} "
        f"| {ratio:.2f}x (rounds {' '.join(f'{p:.2f}' for p in pairs)}; {ru / tu if tu > 0 else float('nan'):.2f}x) "
        f"| {('met' if ratio >= FLOOR else 'NOT met') if pairs else 'no PyTorch pair'} "
        f"| {','.join(sorted({str(x.get('instruction_set', '?')) for x in rs}))} / {','.join(sorted({str(x.get('instruction_set', '?')) for x in ts}))} "
        f"| {med(rs, 'achieved_gflops'):.1f} ({med(rs, 'gemm_gflops'):.1f}, {med(rs, 'gemm_efficiency'):.0%}) "
        f"| {med(ts, 'achieved_gflops'):.1f} ({med(ts, 'gemm_gflops'):.1f}, {med(ts, 'gemm_efficiency'):.0%}) "
        f"| {med(rs, 'planner_batch8_us'):.0f} / {med(ts, 'planner_batch8_us'):.0f} |"
    )
