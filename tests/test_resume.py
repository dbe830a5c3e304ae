"""Same inputs, same numbers; a killed run resumes with nothing lost (issue 13).

The small config trimmed to one set (light 10 deg), with priors on and off,
two estimators, fewer refinement candidates, no noise, surface maps or
geometry sensitivity: Table 1 and the whole Table 2 path. Two uninterrupted runs from scratch give byte-identical
tables; a third, killed with SIGKILL in the middle of the render and again
in the middle of the fits and restarted with the README's command, ends
with the same tables and no output half-written.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SET_ID = "light10_albedo0.6_k0.8"
ESTIMATORS = ["varpro", "koizumi_lm"]
TRIM = [
    "light_angles_deg=[10]", "noise_levels=[]", "surface_maps=[]", "geometry_sensitivity={enabled: false}",
    f"estimators=[{', '.join(ESTIMATORS)}]", "reconstruction={refine_candidates: 20000}", "imaging_conditions=[{name: ideal, prior_sigma_m: 1.0}]",
]
# The science tables: the same config must give the same bytes. runtime.csv and fit_timing.csv are wall-clock times.
SCIENCE_TABLES = ["table1.csv", "table1.md", "table2.csv", "table2.md"]


def command(workdir, *extra):
    """The README's command (`make reproduce`'s: --rerun-incomplete) on the trimmed small config."""
    return [
        sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--cores", "2", "-d", str(workdir),
        "--configfile", str(REPO / "config" / "test.yaml"), "--config", *TRIM,
        "--rerun-incomplete", *extra,
    ]


def run_to_end(workdir):
    run = subprocess.run(command(workdir), cwd=REPO, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout[-5000:] + run.stderr[-5000:]
    return workdir


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    return run_to_end(tmp_path_factory.mktemp("first_run"))


@pytest.fixture(scope="module")
def second_run(tmp_path_factory, first_run):
    return run_to_end(tmp_path_factory.mktemp("second_run"))


def test_same_config_twice_gives_the_same_tables(first_run, second_run):
    for name in SCIENCE_TABLES:
        first, second = (run / "results" / "tables" / name for run in (first_run, second_run))
        assert first.read_bytes() == second.read_bytes(), f"{name} differs between two runs of the same config"
    # Timings live in the runtime tables only.
    header = (first_run / "results/tables/table2.csv").read_text().splitlines()[0].split(",")
    assert not [c for c in header if c.endswith("_seconds")] and "refine_accepted" in header
    assert "fit_seconds" not in (first_run / "results/tables/table1.csv").read_text().splitlines()[0].split(",")
    import pandas as pd

    timing = pd.read_csv(first_run / "results/tables/fit_timing.csv").set_index(["stage", "job"])
    assert len(timing) == 2 + 2 * 2  # Table 1's fits, Table 2's (two estimators)
    assert (timing.loc[("fit", f"{SET_ID}/koizumi_lm"), "fit_seconds"] > 0).all()
    cloud = timing.loc["estimate_cloud"]
    assert (cloud.fit_seconds > 0).all() and (cloud.refit_seconds > 0).all() and (cloud.registration_seconds > 0).all()


def _start(workdir, log_path):
    """The workflow in its own process group (a SIGKILL to the group takes its jobs with it), output to ``log_path``.

    After a kill the README's two commands: ``--unlock`` (a killed Snakemake leaves its lock), then the run.
    """
    if (workdir / ".snakemake" / "locks").is_dir():
        unlock = subprocess.run(command(workdir, "--unlock"), cwd=REPO, capture_output=True, text=True, timeout=300)
        assert unlock.returncode == 0, unlock.stdout[-3000:] + unlock.stderr[-3000:]
    log = open(log_path, "w")
    return subprocess.Popen(command(workdir), cwd=REPO, stdout=log, stderr=subprocess.STDOUT, start_new_session=True), log


def _kill_when(process, log, condition, what, timeout=600):
    """SIGKILL ``process``'s group as soon as ``condition()`` holds; fail if it ends or times out first."""
    deadline = time.monotonic() + timeout
    try:
        while not condition():
            assert process.poll() is None, f"the workflow ended (rc {process.returncode}) before {what}"
            assert time.monotonic() < deadline, f"no {what} within {timeout} s"
            time.sleep(0.02)
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=60)
    finally:
        log.close()
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def _nothing_half_written(workdir):
    """Every output under its real name is whole: rendered sets have every image, .npz load, .json and .csv parse."""
    results = workdir / "results"
    for frames in results.glob("truth/render/*/frames.json"):
        images = json.loads(frames.read_text())["images"]
        assert all((frames.parent / image["file"]).stat().st_size > 0 for image in images), frames.parent
    for render_dir in results.glob("truth/render/*"):
        if not render_dir.name.startswith("."):
            assert (render_dir / "frames.json").is_file(), f"{render_dir} is there without its frames.json"
    for model in results.glob("reconstruction/*/*/*"):
        if not model.name.startswith("."):
            assert (model / "report.json").is_file() and (model / "model" / "points3D.bin").is_file(), model
    for features in results.glob("features/*/*"):
        if not features.name.startswith("."):
            assert (features / "matches.json").is_file() and (features / "database.db").is_file(), features
    for path in results.rglob("*"):
        if any(part.startswith(".") for part in path.relative_to(results).parts):
            continue  # a temporary name: never read
        if path.suffix == ".npz":
            with np.load(path) as data:
                [data[name] for name in data.files]
        elif path.suffix == ".json":
            json.loads(path.read_text())
        elif path.suffix == ".csv":
            assert path.read_text().endswith("\n"), path


def _declared_outputs(workdir):
    """Every output file and directory of the workflow, from Snakemake's --summary."""
    run = subprocess.run(command(workdir, "--summary"), cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    lines = [line.split("\t") for line in run.stdout.splitlines()]
    return {workdir / fields[0] for fields in lines[1:] if fields and fields[0]}


def test_killed_run_resumes_to_the_same_tables(first_run, tmp_path):
    workdir = tmp_path / "killed"
    render_part = workdir / "results" / "truth" / "render" / f".{SET_ID}.partial"

    # 1. Killed in the middle of the render: some images written, the set not complete.
    process, log = _start(workdir, tmp_path / "run1.log")
    _kill_when(process, log, lambda: len(list(render_part.glob("*.exr"))) >= 5, "render halfway")
    assert not (workdir / "results" / "truth" / "render" / SET_ID).exists(), "a half-rendered set is visible under its real name"
    _nothing_half_written(workdir)

    # 2. Restarted, killed again in the middle of a fit (its job started, its outputs not yet there).
    process, log = _start(workdir, tmp_path / "run2.log")
    _kill_when(process, log, lambda: _running_fit(workdir) is not None, "a fit running")
    _nothing_half_written(workdir)

    # 3. Restarted with the same commands: it completes, with the uninterrupted run's tables.
    assert list((workdir / ".snakemake" / "locks").glob("*.lock")), "the killed run left no lock (then the README need not say --unlock)"
    process, log = _start(workdir, tmp_path / "run3.log")
    log.close()
    assert process.wait(timeout=1800) == 0, (tmp_path / "run3.log").read_text()[-5000:]
    for name in SCIENCE_TABLES:
        assert (workdir / "results/tables" / name).read_bytes() == (first_run / "results/tables" / name).read_bytes(), name
    _nothing_half_written(workdir)
    assert not [p for p in (workdir / "results").rglob("*.partial*")], "temporary files left behind"
    assert not list((workdir / ".snakemake" / "incomplete").glob("*")), "Snakemake still marks outputs incomplete"
    # No job wrote outside its declared outputs.
    declared = _declared_outputs(workdir)
    for path in (workdir / "results").rglob("*"):
        if path.is_file():
            assert any(path == output or output in path.parents for output in declared), f"{path} is no declared output"
    dry = subprocess.run(command(workdir, "-n"), cwd=REPO, capture_output=True, text=True, timeout=300)
    assert "Nothing to be done" in dry.stdout + dry.stderr


def _running_fit(workdir):
    """A fit job (Table 1's ``fit`` or Table 2's ``score_cloud``, every estimator of a set in either) that has started (its
    log exists) but not written all its summaries."""
    for stage, results in (("fit", "fits"), ("score_cloud", "fits_cloud")):
        for log_file in (workdir / "logs" / stage).glob("**/*.log"):
            job = log_file.relative_to(workdir / "logs" / stage).with_suffix("")
            if not all((workdir / "results" / results / job / f"{method}.json").exists() for method in ESTIMATORS):
                return job
    return None
