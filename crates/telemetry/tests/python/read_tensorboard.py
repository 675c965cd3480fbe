"""Reads the scalars of one TensorBoard run folder with TensorBoard's own reader.

usage: read_tensorboard.py DIR

Prints one JSON object: {"tags": {tag: [[step, value], ...]}, "files": n} as
`tensorboard.backend.event_processing.event_accumulator.EventAccumulator` loads them (every
event file of DIR, in name order; a torn last record ends a file's read). Non-finite values are
printed as the strings "nan", "inf", "-inf".
"""
import json
import math
import os
import sys

from tensorboard.backend.event_processing import event_accumulator


def number(v):
    if math.isnan(v):
        return "nan"
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return v


def main():
    folder = sys.argv[1]
    acc = event_accumulator.EventAccumulator(folder, size_guidance={"scalars": 0})
    acc.Reload()
    tags = {
        tag: [[e.step, number(e.value)] for e in acc.Scalars(tag)]
        for tag in acc.Tags()["scalars"]
    }
    files = sum(1 for f in os.listdir(folder) if "tfevents" in f)
    print(json.dumps({"tags": tags, "files": files}))


if __name__ == "__main__":
    main()
