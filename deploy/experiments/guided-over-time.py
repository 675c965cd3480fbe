"""Guided fraction per task over a run, from runs/<id>/episodes.mcap (terl.v1.EpisodeSummary).

Usage: guided-over-time.py RUN_DIR [--bins N]

Episodes are taken in log order and cut into N bins of equal env steps; each cell is the share
of that task's env steps in the bin that executed the Action Network (guided_steps / length),
with the task's training success in the bin beside it. Prints a Markdown table. Decodes with the
schema embedded in the file (the `mcap` and `mcap-protobuf-support` packages of
.deps/mcap-venv); nothing of terl is imported.
"""

import sys
from collections import defaultdict

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory


def main(run_dir: str, bins: int) -> None:
    episodes = []
    with open(f"{run_dir}/episodes.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _s, _c, msg, ep in reader.iter_decoded_messages(topics=["/episodes"]):
            episodes.append((msg.log_time, ep.task, ep.length, ep.guided_steps, ep.success))
    episodes.sort()
    if not episodes:
        sys.exit(f"{run_dir}/episodes.mcap has no episode")
    total = sum(e[2] for e in episodes)
    tasks = sorted({e[1] for e in episodes}, key=[e[1] for e in episodes].index)
    cells = [defaultdict(lambda: [0, 0, 0, 0]) for _ in range(bins)]
    done = 0
    for _t, task, length, guided, success in episodes:
        b = min(bins - 1, done * bins // total)
        c = cells[b][task]
        c[0] += guided
        c[1] += length
        c[2] += int(success)
        c[3] += 1
        done += length
    short = [t.removesuffix("-v3") for t in tasks]
    print("| env steps | " + " | ".join(short) + " |")
    print("|---" * (len(tasks) + 1) + "|")
    for b in range(bins):
        lo, hi = b * total // bins, (b + 1) * total // bins
        row = []
        for t in tasks:
            g, n, s, e = cells[b][t]
            row.append(f"{100 * g / n:.0f} % ({s}/{e})" if n else "–")
        print(f"| {lo // 1000}k–{hi // 1000}k | " + " | ".join(row) + " |")


if __name__ == "__main__":
    args = sys.argv[1:]
    n = 5
    if "--bins" in args:
        i = args.index("--bins")
        n = int(args[i + 1])
        del args[i : i + 2]
    if len(args) != 1:
        sys.exit(__doc__)
    main(args[0], n)
