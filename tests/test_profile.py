"""profiles/default: how often Snakemake's scheduler looks at the waiting jobs.

Snakemake looks at the ready jobs again one timespan of its job rate limit
after every round that leaves some waiting, and every job that finishes
starts another chain of such looks; with its default limit (100 jobs a
second) a run of a few hundred jobs made hundreds of rounds a second. The
shipped profile sets a 10-second timespan. This runs a small workflow of its
own under that profile and counts the rounds in Snakemake's debug log.
"""

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
JOBS = 16

SNAKEFILE = f"""
rule all:
    input: expand("out/{{i}}.txt", i=range({JOBS}))

rule wait:
    output: "out/{{i}}.txt"
    shell: "sleep 0.5; touch {{output}}"
"""


def scheduling_rounds(tmp_path, *args):
    (tmp_path / "Snakefile").write_text(SNAKEFILE)
    run = subprocess.run(
        [sys.executable, "-m", "snakemake", "-s", "Snakefile", "--cores", "1", "--verbose",
         "--workflow-profile", str(REPO / "profiles" / "default"), *args],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert len(list((tmp_path / "out").iterdir())) == JOBS
    return (run.stdout + run.stderr).count("Ready jobs: ")


def test_the_default_profile_looks_at_waiting_jobs_seldom(tmp_path):
    # One round per finished job, and a few looks of the chains in between (17);
    # Snakemake's own default made between 4 and 5 rounds a job here (73).
    rounds = scheduling_rounds(tmp_path)
    assert JOBS <= rounds <= 3 * JOBS, rounds


def test_snakemakes_own_limit_would_look_far_more_often(tmp_path):
    # The same workflow under Snakemake's default limit: the count above is the
    # profile's doing, not this workflow's.
    rounds = scheduling_rounds(tmp_path, "--max-jobs-per-timespan", "100/1s")
    assert rounds > 3 * JOBS, rounds
