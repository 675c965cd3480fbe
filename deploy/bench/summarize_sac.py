#!/usr/bin/env python3
"""Side-by-side table of compare_sac.sh output: per config, Rust/PyTorch ratios and the floors.

`ratio` is the median over rounds of each Rust run's updates/s over the PyTorch run right after
it (the two saw about the same background load), `rounds` lists every round's ratio and
`of medians` divides the medians instead. Floors (2 threads, same run, same machine): updates/s
>= 1.0x PyTorch at 3x400/1280, 3x400/256 and 2x256/256; GEMM efficiency (the update's GFLOP/s
over the same GEMM shapes alone) >= 85 % at 3x400/1280 and >= 70 % at 2x256/256; batch-8 policy
inference (3x400) >= 3x faster than PyTorch."""
import statistics
import sys

from bench_runs import isa, med, ratios, read_runs, update_ratios

RATIO_FLOOR = 1.0
EFFICIENCY_FLOOR = {(3, 400, 1280): 0.85, (2, 256, 256): 0.70}
INFERENCE_FLOOR = 3.0

runs = read_runs(sys.stdin)


def verdict(ok):
    return "met" if ok else "NOT met"


print(
    "| net | batch | threads | ISA Rust / PyTorch | Rust upd/s | PyTorch upd/s | ratio (rounds; of medians) "
    "| Rust GFLOP/s (GEMM-rate, eff) | PyTorch GFLOP/s (GEMM-rate, eff) | infer b8 µs Rust / PyTorch (x) | floors |"
)
print("|---|---|---|---|---|---|---|---|---|---|---|")
for key in sorted(runs, key=lambda k: (-k[2], -k[1], k[3])):
    layers, hidden, batch, threads = key
    rs, ts = runs[key]["rust"], runs[key]["torch"]
    ru, tu = med(rs, "updates_per_s"), med(ts, "updates_per_s")
    pairs = update_ratios(rs, ts)
    ratio = statistics.median(pairs) if pairs else float("nan")
    eff = med(rs, "gemm_efficiency")
    inf_pairs = ratios(
        rs, ts, lambda r, t: t["inference_batch8_us"], lambda r, t: r["inference_batch8_us"]
    )
    inf = statistics.median(inf_pairs) if inf_pairs else float("nan")
    floors = []
    if threads == 2:
        floors.append(f"ratio {verdict(ratio >= RATIO_FLOOR) if pairs else 'no PyTorch pair'}")
        want = EFFICIENCY_FLOOR.get((layers, hidden, batch))
        if want is not None and rs:
            floors.append(f"eff>={want:.0%} {verdict(eff >= want)}")
    if (layers, hidden) == (3, 400):
        floors.append(
            f"infer>={INFERENCE_FLOOR:.0f}x {verdict(inf >= INFERENCE_FLOOR) if inf_pairs else 'no PyTorch pair'}"
        )
    rounds = " ".join(f"{p:.2f}" for p in pairs)
    print(
        f"| {layers}x{hidden} | {batch} | {threads} | {isa(rs)} / {isa(ts)} | {ru:.2f} | {tu:.2f} "
        f"| {ratio:.2f}x ({rounds}; {ru / tu if tu > 0 else float('nan'):.2f}x) "
        f"| {med(rs, 'achieved_gflops'):.1f} ({med(rs, 'gemm_gflops'):.1f}, {eff:.0%}) "
        f"| {med(ts, 'achieved_gflops'):.1f} ({med(ts, 'gemm_gflops'):.1f}, {med(ts, 'gemm_efficiency'):.0%}) "
        f"| {med(rs, 'inference_batch8_us'):.0f} / {med(ts, 'inference_batch8_us'):.0f} ({inf:.1f}x) "
        f"| {', '.join(floors) or '-'} |"
    )
