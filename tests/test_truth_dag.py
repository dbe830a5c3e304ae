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
WORLD_RULES = {"fetch_shape_model", "prepare_shape", "imaging_geometry", "condition_geometry", "render", "render_condition", "add_noise", "mission"}
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


_DRY_RUNS = {}


def config_jobs(name: str, tmp_path_factory) -> list[dict]:
    """The jobs of one shipped config's forced dry run, run once per module."""
    if name not in _DRY_RUNS:
        _DRY_RUNS[name] = dry_run_jobs(REPO / "config" / name, tmp_path_factory.mktemp("dag"))
    return _DRY_RUNS[name]


# conditions_geometry.yaml: conditions of their own views, Sun and relief, rendered by rule render_condition.
@pytest.fixture(scope="module", params=["test.yaml", "config.yaml", "conditions_geometry.yaml"])
def jobs(request, tmp_path_factory):
    return config_jobs(request.param, tmp_path_factory)


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
    for job in (job for job in jobs if job["rule"] in ("render", "render_condition", "add_noise", "imaging_geometry", "condition_geometry")):
        assert all("truth" in path for path in job["output"]), job


def test_conditions_of_their_own_views_sun_and_relief_render_their_own_sets_and_start_and_score_from_them(tmp_path_factory):
    """conditions_geometry.yaml: amica starts from the base sets' surface-map renders; oblique (latitude 20, Sun out of
    plane) and relief render their own copy of each, oblique at its own cameras; each condition's mission and scoring
    read its own render."""
    jobs = config_jobs("conditions_geometry.yaml", tmp_path_factory)
    base_sets = ["light0_albedo0.6_k0.8", "light10_albedo0.6_k0.8"]
    renders = {job["output"][0]: job["input"] for job in jobs if job["rule"] == "render_condition"}
    assert sorted(renders) == sorted(f"results/truth/render/{set_id}_map-field_imaging-{name}" for set_id in base_sets for name in ("oblique", "relief"))
    for output, inputs in renders.items():
        cameras = "results/truth/geometry/cameras_lat20.json" if output.endswith("oblique") else "results/truth/geometry/cameras.json"
        assert inputs == ["results/shape/model.npz", cameras]
    assert [job["output"] for job in jobs if job["rule"] == "condition_geometry"] == [["results/truth/geometry/cameras_lat20.json"]]
    for rule in ("mission", "score_cloud"):
        read = {(job["output"][0].split("/")[2], path) for job in jobs if job["rule"] == rule for path in job["input"] if path.startswith("results/truth/render/")}
        assert read == {(name, f"results/truth/render/{set_id}_map-field" + ("" if name == "amica" else f"_imaging-{name}"))
                        for set_id in base_sets for name in ("amica", "oblique", "relief")}, rule
