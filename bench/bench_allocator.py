#!/usr/bin/env python3
"""Benchmark the jobs' memory allocator setting (``core/allocator.py``) on a finished run's Table 2 stages.

Every job of the workflow runs with glibc's malloc told to keep large
blocks for reuse (``ALLOCATOR_ENV``) instead of mapping each afresh. This
script runs the two largest Table 2 stages, the mesh fit (``mesh_light``) and
the refinement (``refine_cloud``), of one set of a finished run, each in a
fresh process as a job runs, alternately without and with the setting (so that
a machine that slows down slows both), and prints per stage the median
seconds of each, their ratio, the peak memory of each (the child's
``ru_maxrss``) and whether the two outputs are the same to the bit. The
outputs go to a temporary folder; the run's files are only read.

    make reproduce                                 # a finished run, in results/
    .venv/bin/python bench/bench_allocator.py      # amica, light 0, albedo 0.7, k 1, priors on; 3 repeats, ~5 min
    .venv/bin/python bench/bench_allocator.py --results /tmp/run/results --job ideal/light10_albedo0.5_k0.8/priors-off

The stages' settings are read from ``--config`` (the default config's, as the
run had them).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "workflow"))
from asteroid_photometry.core.allocator import ALLOCATOR_ENV  # noqa: E402

# What an output records of its own run time (the mesh fit's seconds): not compared.
TIMING_KEYS = {"seconds"}
# A stage's job, as its rule script calls it: the library function and its arguments (paths under the run's results).
STAGE_CODE = {
    "mesh_light": "from asteroid_photometry.experiments.table2 import mesh_light_stage as stage\n"
    "stage(f'{r}/registration/{job}.npz', f'{r}/reconstruction/{job}', f'{r}/mission/{set_path}', f'{r}/refined_cloud/{job}.npz', out)",
    "refine_cloud": "import yaml\n"
    "from asteroid_photometry.core.config import validate_config\n"
    "from asteroid_photometry.experiments.table2 import refine_stage as stage, stage_settings\n"
    "settings = stage_settings(validate_config(yaml.safe_load(open(config)))['reconstruction'], 'refine')\n"
    "stage(f'{r}/registration/{job}.npz', f'{r}/reconstruction/{job}', f'{r}/mission/{set_path}', settings, out)",
}


def run_job(stage: str, results: Path, job: str, config: Path, out: Path, allocator: bool) -> tuple[float, float]:
    """Seconds and peak memory (MiB) of one stage's job in a fresh process, with or without the allocator setting."""
    environ = {key: value for key, value in os.environ.items() if key not in ALLOCATOR_ENV}
    environ.update({"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    if allocator:
        environ.update(ALLOCATOR_ENV)
    set_path = job.rsplit("/", 1)[0]
    code = (
        f"import sys; sys.path.insert(0, {str(ROOT / 'workflow')!r})\n"
        f"r, job, set_path, out, config = {str(results)!r}, {job!r}, {set_path!r}, {str(out)!r}, {str(config)!r}\n" + STAGE_CODE[stage]
    )
    tick = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-c", code], env=environ, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - tick
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{stage} on {job} failed (exit status {os.waitstatus_to_exitcode(status)}); is {results} a finished run's results?")
    return seconds, usage.ru_maxrss / 1024


def same_output(first: Path, second: Path) -> bool:
    """Whether two .npz outputs hold the same arrays, to the bit, but for the time they record."""
    with np.load(first, allow_pickle=False) as a, np.load(second, allow_pickle=False) as b:
        keys = sorted(set(a.files) - TIMING_KEYS)
        return keys == sorted(set(b.files) - TIMING_KEYS) and all(np.array_equal(a[key], b[key], equal_nan=a[key].dtype.kind in "fc") for key in keys)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", type=Path, default=ROOT / "results", help="a finished run's results/ (default: results)")
    parser.add_argument("--job", default="amica/light0_albedo0.7_k1/priors-on", help="imaging/set/priors-on|off")
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    parser.add_argument("--stages", nargs="+", default=list(STAGE_CODE), choices=list(STAGE_CODE))
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"{args.job} of {args.results}; {args.repeats} runs each, alternating; the allocator setting: {ALLOCATOR_ENV}")
    print(f"{'stage':<14}{'default s':>11}{'setting s':>11}{'ratio':>8}{'default MiB':>13}{'setting MiB':>13}  same output")
    with tempfile.TemporaryDirectory() as scratch:
        for stage in args.stages:
            times, memory = {False: [], True: []}, {False: 0.0, True: 0.0}
            outputs = {flag: Path(scratch) / f"{stage}-{flag}.npz" for flag in (False, True)}
            for _ in range(args.repeats):
                for flag in (False, True):
                    seconds, peak = run_job(stage, args.results, args.job, args.config, outputs[flag], flag)
                    times[flag].append(seconds)
                    memory[flag] = max(memory[flag], peak)
            plain, tuned = statistics.median(times[False]), statistics.median(times[True])
            print(f"{stage:<14}{plain:>11.1f}{tuned:>11.1f}{tuned / plain:>8.2f}{memory[False]:>13.0f}{memory[True]:>13.0f}  {same_output(*outputs.values())}")


if __name__ == "__main__":
    main()
