#!/usr/bin/env python3
"""Side-by-side table of compare_sac.sh output: per config, Rust/PyTorch ratios and the floors.

`ratio` is the median over rounds of each Rust run's updates/s over the PyTorch run right after
it (the two saw about the same background load), `rounds` lists every round's ratio and
`of medians` divides the medians instead. Floors (2 threads, same run, same machine): updates/s
>= 1.0x PyTorch at 3x400/1280, 3x400/256 and 2x256/256; GEMM efficiency (the update's GFLOP/s
over the same GEMM shapes alone) >= 85 % at 3x400/1280 and >= 70 % at 2x256/256; batch-8 policy
inference (3x400) >= 3x faster than PyTorch."""
import json
import statistics
import sys
from collections import defaultdict

RATIO_FLOOR = 1.0
EFFICIENCY_FLOOR = {(3, 400, 1280): 0.85, (2, 256, 256): 0.70}
INFERENCE_FLOOR = 3.0

runs = defaultdict(lambda: defaultdict(list))
for line in sys.stdin:
    line = line.strip()
    if not line.startswith("{"):
        continue
    try:
        r = json.loads(line)
        c = r["config"]
        key = (c["layers"], c["hidden"], c["batch"], c["threads"])
        impl = "rust" if r["implementation"].startswith("terl") else "torch"
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        print(f"skipped a malformed line ({e!r}): {line[:80]}", file=sys.stderr)
        continue
    runs[key][impl].append(r)


def med(rs, field):
    return statistics.median(x[field] for x in rs) if rs else float("nan")


def isa(rs):
    return ",".join(sorted({x.get("instruction_set", "?") for x in rs})) or "?"


print(
    "| net | batch | threads | ISA Rust / PyTorch | Rust upd/s | PyTorch upd/s | ratio (rounds; of medians) "
    "| Rust GFLOP/s (GEMM-rate, eff) | PyTorch GFLOP/s (GEMM-rate, eff) | infer b8 µs Rust / PyTorch (x) | floors |"
)
print("|---|---|---|---|---|---|---|---|---|---|---|")
for key in sorted(runs, key=lambda k: (-k[2], -k[1], k[3])):
    layers, hidden, batch, threads = key
    rs, ts = runs[key]["rust"], runs[key]["torch"]
    ru, tu = med(rs, "updates_per_s"), med(ts, "updates_per_s")
    pairs = [r["updates_per_s"] / t["updates_per_s"] for r, t in zip(rs, ts)]
    ratio = statistics.median(pairs) if pairs else float("nan")
    eff = med(rs, "gemm_efficiency")
    inf_pairs = [t["inference_batch8_us"] / r["inference_batch8_us"] for r, t in zip(rs, ts)]
    inf = statistics.median(inf_pairs) if inf_pairs else float("nan")
    floors = []
    if threads == 2:
        floors.append(f"ratio {'met' if ratio >= RATIO_FLOOR else 'NOT met'}")
        want = EFFICIENCY_FLOOR.get((layers, hidden, batch))
        if want is not None:
            floors.append(f"eff>={want:.0%} {'met' if eff >= want else 'NOT met'}")
    if (layers, hidden) == (3, 400):
        floors.append(f"infer>={INFERENCE_FLOOR:.0f}x {'met' if inf >= INFERENCE_FLOOR else 'NOT met'}")
    rounds = " ".join(f"{p:.2f}" for p in pairs)
    print(
        f"| {layers}x{hidden} | {batch} | {threads} | {isa(rs)} / {isa(ts)} | {ru:.2f} | {tu:.2f} "
        f"| {ratio:.2f}x ({rounds}; {ru / tu:.2f}x) "
        f"| {med(rs, 'achieved_gflops'):.1f} ({med(rs, 'gemm_gflops'):.1f}, {eff:.0%}) "
        f"| {med(ts, 'achieved_gflops'):.1f} ({med(ts, 'gemm_gflops'):.1f}, {med(ts, 'gemm_efficiency'):.0%}) "
        f"| {med(rs, 'inference_batch8_us'):.0f} / {med(ts, 'inference_batch8_us'):.0f} ({inf:.1f}x) "
        f"| {', '.join(floors) or '-'} |"
    )
