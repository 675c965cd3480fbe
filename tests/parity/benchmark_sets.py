#!/usr/bin/env python3
"""Write Meta-World's task list and benchmark task sets to tests/fixtures/metaworld/benchmarks.json.

Reads them from the installed metaworld package (the venv made by tests/parity/setup-venv.sh):

    .deps/venv/bin/python tests/parity/benchmark_sets.py

`all` is `ALL_V3_ENVIRONMENTS` in its order (which is also MT50's, `MT50_V3 = ALL_V3_ENVIRONMENTS`);
`mt10`, `mt50`, `ml10-train`, `ml10-test`, `ml45-train`, `ml45-test` are the benchmark
dictionaries of `metaworld/env_dict.py`, each in its own order. The Rust test
`crates/sim/tests/task_sets.rs` compares terl's registry and task sets with this file.
The output is deterministic: re-running gives a byte-identical file.
"""

from __future__ import annotations

import json
import sys
from importlib.metadata import version
from pathlib import Path

from metaworld import env_dict

OUT = Path(__file__).resolve().parents[1] / "fixtures" / "metaworld" / "benchmarks.json"


def main() -> int:
    sets = {
        "all": list(env_dict.ALL_V3_ENVIRONMENTS.keys()),
        "mt10": list(env_dict.MT10_V3.keys()),
        "mt50": list(env_dict.MT50_V3.keys()),
        "ml10-train": list(env_dict.ML10_V3["train"].keys()),
        "ml10-test": list(env_dict.ML10_V3["test"].keys()),
        "ml45-train": list(env_dict.ML45_V3["train"].keys()),
        "ml45-test": list(env_dict.ML45_V3["test"].keys()),
    }
    doc = {"metaworld": version("metaworld"), "source": "metaworld/env_dict.py", "sets": sets}
    OUT.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {OUT}: " + ", ".join(f"{k} {len(v)}" for k, v in sets.items()), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
