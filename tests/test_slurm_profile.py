"""profiles/slurm, checked by dry runs (no SLURM needed; make test-cluster runs it on a real one).

Every job's resources as Snakemake would submit them: partition and account
from the environment or the command line, each cluster rule's memory and
time limit from the profile, the tables and plots local.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / "profiles" / "slurm"
# The full config without a local shape model: every rule, the download included.
PLAN = ["-n", "--workflow-profile", str(PROFILE), "--configfile", str(REPO / "config" / "config.yaml")]


def dry_run(tmp_path, *args, env=None):
    environment = {key: value for key, value in os.environ.items() if not key.startswith("SBATCH_")}
    environment.update(env or {})
    run = subprocess.run(
        [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "-d", str(tmp_path), *PLAN, *args],
        cwd=REPO, env=environment, capture_output=True, text=True, timeout=300,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    jobs = []
    for block in re.split(r"\n(?=(?:local)?rule \w+:\n)", run.stdout):
        name = re.match(r"(?:local)?rule (\w+):\n", block)
        resources = re.search(r"^    resources: (.*)$", block, re.MULTILINE)
        if name and resources:
            jobs.append((name[1], dict(item.split("=", 1) for item in resources[1].split(", "))))
    assert jobs, run.stdout
    return jobs


def profile():
    with open(PROFILE / "config.v8+.yaml") as file:
        return yaml.safe_load(file)


def local_rules():
    """The Snakefile's localrules."""
    block = re.search(r"^localrules:\n((?:    \w+,\n)+)", (REPO / "Snakefile").read_text(), re.MULTILINE)
    return set(re.findall(r"\w+", block[1]))


def test_partition_and_account_come_from_the_environment_and_every_cluster_rule_is_sized(tmp_path):
    jobs = dry_run(tmp_path, env={"SBATCH_PARTITION": "short", "SBATCH_ACCOUNT": "proj42"})
    assert {(resources.get("slurm_partition"), resources.get("slurm_account")) for _, resources in jobs} == {("short", "proj42")}
    sized = profile()["set-resources"]
    local = local_rules()
    assert {rule for rule, _ in jobs if rule.startswith(("tabulate_", "plot_"))} <= local
    cluster_rules = {rule for rule, _ in jobs if rule not in local}
    assert cluster_rules == set(sized), "set-resources must name exactly the rules that run as cluster jobs"
    for rule, resources in jobs:
        if rule in sized:
            assert int(resources["mem_mb"]) == sized[rule]["mem_mb"], rule
            assert int(resources["runtime"]) == sized[rule]["runtime"], rule


def test_the_rules_of_another_shipped_config_are_sized_too(tmp_path):
    jobs = dry_run(tmp_path, "--configfile", str(REPO / "config" / "conditions_geometry.yaml"))
    sized = profile()["set-resources"]
    assert "render_condition" in {rule for rule, _ in jobs}
    assert {rule for rule, _ in jobs if rule not in local_rules()} <= set(sized)
    for rule, resources in jobs:
        if rule in sized:
            assert int(resources["mem_mb"]) == sized[rule]["mem_mb"] and int(resources["runtime"]) == sized[rule]["runtime"], rule


def test_without_them_no_partition_or_account_is_asked_for(tmp_path):
    jobs = dry_run(tmp_path)
    assert not [rule for rule, resources in jobs if "slurm_partition" in resources or "slurm_account" in resources]


def test_the_command_line_gives_them_too_and_keeps_the_rules_resources(tmp_path):
    jobs = dry_run(tmp_path, "--default-resources", "slurm_partition=long", "slurm_account=proj7", env={"SBATCH_PARTITION": "short"})
    assert {(resources.get("slurm_partition"), resources.get("slurm_account")) for _, resources in jobs} == {("long", "proj7")}
    sized = profile()["set-resources"]
    for rule, resources in jobs:
        if rule in sized:
            assert int(resources["mem_mb"]) == sized[rule]["mem_mb"], rule
            assert int(resources["runtime"]) == sized[rule]["runtime"], rule
