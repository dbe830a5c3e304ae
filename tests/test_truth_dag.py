"""No truth in the image-only path: a walk of the workflow's DAG (dry run) over every job Table 2's estimates come from.

Every file holding truth (the renderer's record of true poses, light,
albedo and k; the mission sets' truth files; the true cameras) lies under a
path containing ``truth``. The world rules create it; the scoring rules read
it; no other job upstream of an estimate may.
"""

import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: The simulation of the world: they make the truth and the mission sets from it.
WORLD_RULES = {"fetch_shape_model", "prepare_shape", "imaging_geometry", "render", "add_noise", "mission"}
#: The image-only path of Table 2, up to its estimates.
IMAGE_ONLY_RULES = {"match_features", "reconstruct", "register_cloud", "refine_cloud", "estimate_cloud"}
JOB_HEADER = re.compile(r"^(?:local)?rule (\w+):$")


def dry_run_jobs(configfile: Path, workdir: Path) -> list[dict]:
    """Every job of a forced dry run: its rule, input and output paths."""
    run = subprocess.run(
        [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "-n", "--forceall", "--cores", "1", "-d", str(workdir), "--configfile", str(configfile)],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    jobs, job = [], None
    for line in run.stdout.splitlines():
        header = JOB_HEADER.match(line)
        if header:
            job = {"rule": header.group(1), "input": [], "output": []}
            jobs.append(job)
        elif job is not None and line.startswith("    input: "):
            job["input"] = [path.strip() for path in line.removeprefix("    input: ").split(",")]
        elif job is not None and line.startswith("    output: "):
            job["output"] = [path.strip() for path in line.removeprefix("    output: ").split(",")]
    return jobs


def ancestors(jobs: list[dict], of_rule: str) -> list[dict]:
    """The jobs of ``of_rule`` and every job they depend on, through the files they read."""
    producer = {path: job for job in jobs for path in job["output"]}
    seen, stack = {}, [job for job in jobs if job["rule"] == of_rule]
    while stack:
        job = stack.pop()
        if id(job) in seen:
            continue
        seen[id(job)] = job
        stack.extend(producer[path] for path in job["input"] if path in producer)
    return list(seen.values())


def truth_readers(jobs: list[dict]) -> dict[str, set]:
    """Rule -> the truth paths its jobs read."""
    readers = defaultdict(set)
    for job in jobs:
        for path in job["input"]:
            if "truth" in path:
                readers[job["rule"]].add(path)
    return readers


@pytest.fixture(scope="module", params=["test.yaml", "config.yaml"])
def jobs(request, tmp_path_factory):
    return dry_run_jobs(REPO / "config" / request.param, tmp_path_factory.mktemp("dag"))


def test_no_job_upstream_of_an_estimate_reads_truth_but_the_world(jobs):
    upstream = ancestors(jobs, "estimate_cloud")
    rules = {job["rule"] for job in upstream}
    assert IMAGE_ONLY_RULES <= rules, f"the image-only path's rules missing from the DAG: {IMAGE_ONLY_RULES - rules}"
    offenders = {rule: sorted(paths)[:3] for rule, paths in truth_readers(upstream).items() if rule not in WORLD_RULES}
    assert not offenders, f"rules of the image-only path read truth: {offenders}"


def test_the_scoring_reads_the_truth_and_the_walk_would_see_it(jobs):
    """The check above can fail: the scoring rule, downstream of the estimates, does read truth paths."""
    readers = truth_readers(ancestors(jobs, "score_cloud"))
    assert any("/truth/mission/" in path for path in readers["score_cloud"])
    assert any("/truth/render/" in path for path in readers["score_cloud"])
    assert "score_cloud" not in {job["rule"] for job in ancestors(jobs, "estimate_cloud")}


def test_the_world_writes_the_mission_set_and_the_truth_apart(jobs):
    for job in (job for job in jobs if job["rule"] == "mission"):
        truth = [path for path in job["output"] if "truth" in path]
        mission = [path for path in job["output"] if "truth" not in path]
        assert len(truth) == 1 and len(mission) == 1 and mission[0].startswith("results/mission/")
    for job in (job for job in jobs if job["rule"] in ("render", "add_noise", "imaging_geometry")):
        assert all("truth" in path for path in job["output"]), job
