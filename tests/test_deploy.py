"""The workflow as users adopt it: deployed with snakedeploy into an empty folder and run there as a module."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# What a clone holds, less what a run or the venv leaves in it.
NOT_IN_A_CLONE = shutil.ignore_patterns(".git", ".venv", "results", "logs", "benchmarks", "resources", ".snakemake", "__pycache__", ".pytest_cache")


def run(command, cwd, timeout=900):
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ['PATH']}"}
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def job_counts(stdout):
    counts = {}
    for line in stdout.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[1].isdigit():
            counts[parts[0]] = int(parts[1])
    return counts


@pytest.fixture(scope="module")
def deployed(tmp_path_factory):
    """An empty folder with the workflow deployed by snakedeploy, its module pointed at this checkout."""
    root = tmp_path_factory.mktemp("deploy")
    source = root / "source"
    shutil.copytree(REPO, source, ignore=NOT_IN_A_CLONE)
    dest = root / "analysis"
    deploy = run([str(BIN / "snakedeploy"), "deploy-workflow", str(source), str(dest), "--branch", "main"], cwd=root)
    assert deploy.returncode == 0, deploy.stdout + deploy.stderr
    module_snakefile = dest / "workflow" / "Snakefile"
    text = module_snakefile.read_text()
    # For a local source snakedeploy names the top-level Snakefile relative to the source; point it at this checkout.
    assert 'snakefile: \n        "Snakefile"' in text or 'snakefile:\n        "Snakefile"' in text, text
    module_snakefile.write_text(text.replace('"Snakefile"', f'"{REPO / "Snakefile"}"'))
    assert "use rule * from" in text
    # snakedeploy copies the shipped configs for the user to edit.
    assert (dest / "config" / "config.yaml").is_file() and (dest / "config" / "README.md").is_file()
    return dest


def write_user_config(dest, **keys):
    (dest / "config" / "config.yaml").write_text(yaml.safe_dump(keys))


def test_module_dry_run_follows_the_users_own_config(deployed):
    write_user_config(
        deployed, albedos=[0.3, 0.4], minnaert_k=[0.9], light_angles_deg=[20], noise_levels=[], surface_maps=[],
        reconstruction={"enabled": False},
    )
    dry = run([str(BIN / "snakemake"), "-n", "--cores", "1"], cwd=deployed)
    assert dry.returncode == 0, dry.stdout + dry.stderr
    jobs = job_counts(dry.stdout)
    assert jobs["render"] == 2 and jobs["fit"] == 2 and jobs["tabulate_table1"] == 1
    # The shape model is the one that ships with the workflow: nothing to download.
    assert "fetch_shape_model" not in jobs and jobs["prepare_shape"] == 1
    assert "match_features" not in jobs and "reconstruct" not in jobs and "add_noise" not in jobs
    # A typo in the user's config is named, as it is in the repository's own.
    write_user_config(deployed, albedos=[0.3], minnaert_k=[0.9], light_angles_deg=[20], albdeos=[0.1])
    bad = run([str(BIN / "snakemake"), "-n", "--cores", "1"], cwd=deployed)
    assert bad.returncode != 0 and "albdeos" in bad.stdout + bad.stderr


def test_module_runs_the_small_config_to_table1(deployed):
    small = yaml.safe_load((REPO / "config" / "test.yaml").read_text())
    small.update(noise_levels=[], surface_maps=[], reconstruction={"enabled": False})
    write_user_config(deployed, **small)
    result = run([str(BIN / "snakemake"), "--cores", "2", "results/tables/table1.csv"], cwd=deployed)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-4000:]
    table = pd.read_csv(deployed / "results" / "tables" / "table1.csv")
    assert sorted(table.set_id.unique()) == ["light0_albedo0.6_k0.8", "light10_albedo0.6_k0.8"]
    paper_method = table[table.method == "koizumi_lm"]
    assert (paper_method.light_dir_err_deg < 0.003).all() and (paper_method.k_err.abs() < 1e-3).all()
    # The run's files are in the user's folder.
    assert (deployed / "results" / "truth" / "render" / "light0_albedo0.6_k0.8" / "frames.json").is_file()
    assert (deployed / "logs").is_dir() and (deployed / "benchmarks").is_dir()
