#!/usr/bin/env python3
"""Benchmark what a stage's job pays to import its library module, with and without pandas.

Every job of the workflow is a fresh Python process that imports the
library module of its stage (``asteroid_photometry.experiments.<module>``)
before it does any work; a full run has some 900 such jobs. pandas is
imported only where a table is built. This script times, in fresh
processes, the import of each stage module alone and followed by
``import pandas`` (what every job paid when the modules imported pandas at
the top), and prints the medians of ``--repeats`` runs, their difference
and their ratio. Both variants run alternately in the same loop, so a
machine that slows down slows both.

    .venv/bin/python bench/bench_imports.py               # 7 repeats, ~1 min
    .venv/bin/python bench/bench_imports.py --repeats 15
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

WORKFLOW = Path(__file__).resolve().parents[1] / "workflow"
MODULES = ["table1", "table2", "mission", "monte_carlo", "sensitivity", "mismatch"]


def seconds(code: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], cwd=WORKFLOW, check=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    print(f"{'module':<14}{'import s':>10}{'+ pandas s':>12}{'difference s':>14}{'ratio':>8}")
    for module in MODULES:
        code = f"import asteroid_photometry.experiments.{module}"
        alone, with_pandas = [], []
        for _ in range(args.repeats):
            alone.append(seconds(code))
            with_pandas.append(seconds(code + "; import pandas"))
        a, b = statistics.median(alone), statistics.median(with_pandas)
        print(f"{module:<14}{a:>10.2f}{b:>12.2f}{b - a:>14.2f}{b / a:>8.2f}")


if __name__ == "__main__":
    main()
