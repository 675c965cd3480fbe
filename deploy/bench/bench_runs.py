"""Reading and pairing the JSON lines of compare_sac.sh / compare_tep.sh (one Rust run, then the
PyTorch run on the same config right after it), shared by summarize_sac.py and summarize_tep.py."""
import json
import statistics
import sys
from collections import defaultdict


def read_runs(lines):
    """`{(layers, hidden, batch, threads): {"rust": [...], "torch": [...]}}` in input order.

    Lines that are not JSON objects are ignored; objects without a usable config,
    implementation or positive `updates_per_s` are skipped with a message on stderr."""
    runs = defaultdict(lambda: defaultdict(list))
    for line in lines:
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
    return runs


def med(rs, field):
    """Median of a numeric field over runs (NaN when none has it)."""
    xs = []
    for x in rs:
        try:
            xs.append(float(x[field]))
        except (KeyError, TypeError, ValueError):
            pass
    return statistics.median(xs) if xs else float("nan")


def ratios(rs, ts, num, den):
    """Per-round `num(rust, torch) / den(rust, torch)` of paired runs (skips unusable pairs)."""
    out = []
    for r, t in zip(rs, ts):
        try:
            a, b = float(num(r, t)), float(den(r, t))
        except (KeyError, TypeError, ValueError):
            continue
        if b > 0:
            out.append(a / b)
    return out


def update_ratios(rs, ts):
    """Per-round Rust/PyTorch updates/s."""
    return ratios(rs, ts, lambda r, t: r["updates_per_s"], lambda r, t: t["updates_per_s"])


def isa(rs):
    """The instruction sets the runs report, comma-separated."""
    return ",".join(sorted({str(x.get("instruction_set", "?")) for x in rs})) or "?"
