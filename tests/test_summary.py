"""results/summary.md: the headline numbers of the result tables, and the README's quotes of them."""

import re
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from asteroid_photometry.evaluation.summary import (
    SummaryError,
    git_commit,
    number,
    summary_markdown,
    tables_in,
    write_summary,
)

REPO = Path(__file__).resolve().parents[1]
BOUNDS = {"light_dir_err_deg": 0.5, "albedo_err": 0.01, "k_err": 0.01}


def _write(directory: Path, name: str, rows: list[dict]) -> Path:
    path = directory / name
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


@pytest.fixture
def tables(tmp_path):
    """Small tables with known worst values: two sets, the paper's estimator and the baseline."""
    table1 = []
    for set_id, light, albedo_err, k_err in (("light0", 0.002, -3e-7, 1e-6), ("light10", -0.004, 2e-7, -5e-6)):
        for method, scale in (("koizumi_lm", 1.0), ("iwano_linear", 10.0)):
            table1.append({
                "set_id": set_id, "method": method, "status": "ok", "light_deg_err": scale * light,
                "light_dir_err_deg": abs(scale * light), "albedo_err": scale * albedo_err, "k_err": scale * k_err,
                "albedo_rmse": 1e-5, "k_rmse": 2e-5,
            })
    table1.append({"set_id": "light20", "method": "koizumi_lm", "status": "failed: fit: too few observations"})
    _write(tmp_path, "table1.csv", table1)
    _write(tmp_path, "paper.csv", [
        {"light_deg_true": 0, "albedo_true": 0.5, "k_true": 0.7, "light_deg_est": 0.0073, "albedo_est": 0.503, "k_est": 0.699},
        {"light_deg_true": 10, "albedo_true": 0.5, "k_true": 0.7, "light_deg_est": 10.029, "albedo_est": 0.49, "k_est": 0.705},
    ])
    table2 = []
    for imaging in ("ideal", "amica"):
        for priors, light_errors in (("on", (0.1, 0.4, 0.45)), ("off", (0.2, 0.7, 1.3))):
            for index, light in enumerate(light_errors):
                table2.append({
                    "set_id": f"set{index}", "imaging": imaging, "priors": priors, "method": "koizumi_lm", "status": "ok", "registration_ok": True,
                    "light_dir_err_deg_final": light, "albedo_err_final": 0.002 if index else 0.02, "k_err_final": -0.001 if imaging == "ideal" else -0.015,
                })
    _write(tmp_path, "table2.csv", table2)
    _write(tmp_path, "runtime.csv", [
        {"stage": "render", "job": "a", "seconds": 100.0, "max_rss_mb": 300.0},
        {"stage": "render", "job": "b", "seconds": 50.0, "max_rss_mb": 400.0},
        {"stage": "fit", "job": "a/koizumi_lm", "seconds": 30.0, "max_rss_mb": 200.0},
        {"stage": "fit", "job": "TOTAL", "seconds": 30.0, "max_rss_mb": 200.0},
        {"stage": "render", "job": "TOTAL", "seconds": 150.0, "max_rss_mb": 400.0},
    ])
    return tmp_path


def _summary(directory: Path, **kwargs) -> str:
    return summary_markdown(tables_in(directory), config={"albedos": [0.5]}, bounds=BOUNDS, commit="abc123",
                            paper_table1=directory / "paper.csv", **kwargs)


def _headlines(text: str) -> dict[str, str]:
    """The summary's table of headlines: output -> headline."""
    section = text.split("## Headlines", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| ([^|]+?) \| ([^|]+?) \|$", section, re.MULTILINE)
    return {output: headline for output, headline in rows if output != "output"}


def test_number_keeps_two_significant_digits():
    assert [number(v) for v in (0.00058, 0.029, 6.1e-6, 1.44e-5, 12.3, 9.96, 0.5, 1234.5, 0, -0.0025, float("nan"))] == [
        "0.00058", "0.029", "6.1e-6", "1.4e-5", "12", "10", "0.5", "1200", "0", "-0.0025", "n/a",
    ]


def test_summary_has_the_worst_values_and_the_counts(tables):
    text = _summary(tables)
    headlines = _headlines(text)
    # Table 1: the paper's estimator's worst light error (0.004) beside the paper's (0.029); the failed set is counted.
    assert headlines["Table 1"] == "koizumi_lm: worst light error 0.004 deg (paper 0.029 deg)"
    assert "2 of 3 sets ok" in text
    assert "| mean albedo error | 3e-7 | 3e-6 | 0.01 |" in text
    assert "| mean k error | 5e-6 | 5e-5 | 0.005 |" in text
    # Table 2, ideal: with priors all light errors are within 0.5 deg, but set0's albedo error (0.02) is not within 0.01;
    # without, set0 has the same albedo error and the others' light is off by more than 0.5 deg. amica's bounds are
    # light 1 deg and k 0.02: its k error of 0.015 passes there, and without priors set1's light (0.7 deg) does too.
    assert headlines["Table 2"] == (
        "koizumi_lm, final estimate, sets within all three bounds: amica, priors off: 1 / 3, amica, priors on: 2 / 3, "
        "ideal, priors off: 0 / 3, ideal, priors on: 2 / 3"
    )
    assert "| ideal | on | koizumi_lm | 3 / 3 | 3 / 3 | 0.1 to 0.45 | 0.002 to 0.02 | -0.001 | 2 / 3 |" in text
    assert "amica: light 1 deg, albedo 0.01, k 0.02; ideal: light 0.5 deg, albedo 0.01, k 0.01" in text
    # Runtime: the per-stage totals summed, the TOTAL rows not counted as jobs.
    assert headlines["Runtime"] == "180 job-seconds in 3 jobs"
    # Provenance: the commit and the config.
    assert "Commit: `abc123`" in text and "albedos: [0.5]" in text


def test_a_missing_optional_table_is_skipped(tables):
    (tables / "table2.csv").unlink()
    text = summary_markdown(
        {"table1": tables / "table1.csv", "table2": tables / "table2.csv", "runtime": tables / "runtime.csv"},
        config=None, bounds=BOUNDS,
    )
    assert "Table 2" not in text and "## Runtime" in text and "## Table 1" in text


def test_a_missing_table1_is_a_clear_error(tables):
    (tables / "table1.csv").unlink()
    with pytest.raises(SummaryError, match="Table 1 is required.*table1.csv"):
        summary_markdown({"table1": tables / "table1.csv", "runtime": tables / "runtime.csv"}, config=None, bounds=BOUNDS)
    with pytest.raises(SummaryError, match="Table 1 is required"):
        write_summary(tables_in(tables), tables / "summary.md", config=None, bounds=BOUNDS)
    assert not (tables / "summary.md").exists()


def test_commit_is_unknown_outside_a_git_checkout_and_says_when_files_changed(tmp_path):
    assert git_commit(tmp_path) == "unknown"
    git = ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "a.txt").write_text("a")
    subprocess.run([*git, "add", "a.txt"], check=True)
    subprocess.run([*git, "commit", "-qm", "a"], check=True)
    commit = git_commit(tmp_path)
    assert re.fullmatch(r"[0-9a-f]{40}", commit)
    (tmp_path / "a.txt").write_text("b")
    assert git_commit(tmp_path) == commit + " (with uncommitted changes)"


def _readme_outputs_table() -> list[list[str]]:
    """The rows of the README's table of outputs (its last column quotes docs/results/summary.md)."""
    readme = (REPO / "README.md").read_text()
    section = readme.split("## What comes out", 1)[1].split("\n## ", 1)[0]
    rows = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in section.splitlines() if line.startswith("|")]
    assert len(rows) > 2, "README.md: no table under 'What comes out'"
    return rows[2:]


NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?(?:e-?\d+)?(?![\w.])")


def test_every_number_the_readme_quotes_is_in_the_committed_summary():
    """A number in the README's outputs table that the committed summary no longer has is stale."""
    summary = (REPO / "docs" / "results" / "summary.md").read_text()
    headlines = set(_headlines(summary).values())
    quoted = 0
    for row in _readme_outputs_table():
        for value in NUMBER.findall(row[-1].replace("`", "")):
            quoted += 1
            assert any(re.search(rf"(?<![\w.]){re.escape(value)}(?![\w.])", line) for line in headlines), (
                f"README.md quotes {value} ({row[0]}), which docs/results/summary.md's headlines do not have"
            )
    assert quoted >= 5


def test_the_readme_names_the_commit_of_the_committed_summary():
    """The README says which commit its quoted run came from; a new summary without the README following is stale."""
    summary = (REPO / "docs" / "results" / "summary.md").read_text()
    commit = re.search(r"Commit: `([0-9a-f]{7,40})", summary)
    assert commit, "docs/results/summary.md names no commit"
    section = (REPO / "README.md").read_text().split("## What comes out", 1)[1].split("\n## ", 1)[0]
    named = re.findall(r"config it came\s+from: ([0-9a-f]{7,40})\)", section)
    assert named, "README.md's 'What comes out' names no commit for the run it quotes"
    assert commit.group(1).startswith(named[0]), f"README.md names {named[0]}, docs/results/summary.md is of {commit.group(1)[:7]}"
