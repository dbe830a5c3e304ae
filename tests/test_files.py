"""Outputs written whole or not at all; timings kept out of the science tables."""

import json

import numpy as np
import pandas as pd
import pytest

from asteroid_photometry.core import files
from asteroid_photometry.evaluation import metrics


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "table.csv"
    files.write_text(path, "old\n")
    with pytest.raises(RuntimeError):
        with files.replacing(path) as part:
            part.write_text("half")
            raise RuntimeError("killed halfway")
    assert path.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.csv"]


def test_the_temporary_name_keeps_the_suffix_and_is_hidden(tmp_path):
    part = files.partial_path(tmp_path / "estimates.npz")
    assert part.parent == tmp_path and part.name.startswith(".") and part.suffix == ".npz"
    files.savez(tmp_path / "estimates.npz", x=np.arange(3))
    with np.load(tmp_path / "estimates.npz") as data:
        assert data["x"].tolist() == [0, 1, 2]
    files.write_json(tmp_path / "row.json", {"a": 1})
    files.write_csv(pd.DataFrame({"a": [1, 2]}), tmp_path / "t.csv")
    assert json.loads((tmp_path / "row.json").read_text()) == {"a": 1}
    assert (tmp_path / "t.csv").read_text() == "a\n1\n2\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["estimates.npz", "row.json", "t.csv"]


def test_a_directory_appears_whole_and_replaces_the_old_one(tmp_path):
    out = tmp_path / "render" / "set"
    out.mkdir(parents=True)
    (out / "stale.exr").write_text("from an earlier run")
    part = files.partial_directory(out)
    (part / "image_000.exr").write_text("new")
    assert (out / "stale.exr").exists() and not (out / "image_000.exr").exists()  # nothing new visible yet
    files.move_into_place(part, out)
    assert sorted(p.name for p in out.iterdir()) == ["image_000.exr"]
    assert sorted(p.name for p in out.parent.iterdir()) == ["set"]
    # A killed run's temporary directory is cleared by the next.
    (out.parent / ".set.partial").mkdir()
    (out.parent / ".set.partial" / "half.exr").write_text("half")
    assert list(files.partial_directory(out).iterdir()) == []


def test_timings_leave_the_tables_for_fit_timing(tmp_path):
    table = pd.DataFrame({"set_id": ["a"], "k_err": [0.1], "fit_seconds": [1.5], "refit_seconds": [0.2]})
    assert list(metrics.without_timings(table)) == ["set_id", "k_err"]
    summaries = []
    for relative, row in (
        ("results/fits/setA/varpro.json", {"k_err": 0.1, "fit_seconds": 1.5}),
        ("results/fits_cloud/ideal/setA/priors-off/koizumi_lm.json", {"k_err": 0.2, "fit_seconds": 2.0, "refit_seconds": 0.5, "registration_seconds": 3.0}),
    ):
        path = tmp_path / relative
        path.parent.mkdir(parents=True)
        path.write_text(json.dumps(row))
        summaries.append(path)
    timing = metrics.fit_timing_table(summaries)
    assert timing[["stage", "job"]].values.tolist() == [["fit", "setA/varpro"], ["estimate_cloud", "ideal/setA/priors-off/koizumi_lm"]]
    assert timing.fit_seconds.tolist() == [1.5, 2.0] and timing.registration_seconds.iloc[1] == 3.0
    assert "k_err" not in timing
    assert "fit_seconds" not in metrics.TABLE1_COLUMNS


def test_runtime_table_names_each_stage_also_for_a_job_without_wildcards(tmp_path):
    from asteroid_photometry.evaluation import metrics

    paths = []
    for relative, seconds in (("benchmarks/observe/setA.tsv", 2.0), ("benchmarks/observe/setB.tsv", 3.0), ("benchmarks/observation_geometry.tsv", 4.0)):
        path = tmp_path / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("s\th:m:s\tmax_rss\n" + f"{seconds}\t0:00:0{seconds:.0f}\t100.0\n")
        paths.append(path)
    table = metrics.runtime_table(paths)
    assert set(table.stage) == {"observe", "observation_geometry"}
    assert table.set_index(["stage", "job"]).loc[("observation_geometry", "all"), "seconds"] == 4.0
    assert table.set_index(["stage", "job"]).loc[("observe", "TOTAL"), "seconds"] == 5.0
