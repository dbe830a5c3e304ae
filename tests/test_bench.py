"""The estimator benchmark (bench/bench_estimators.py) in its quick mode: every method reaches the same answer; the
blur matrix's (bench/bench_blur_matrix.py) on small discs: both assemblies give the same products; the shot-noise
draws' (bench/bench_shot_noise.py) on two images: the inverse CDF keeps its counts.

Speed is not asserted (it depends on the machine); the answers are.
"""

import csv
import importlib.util
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).parents[1] / "bench" / "bench_estimators.py"


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_estimators", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def quick_run(bench, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    quick = bench.QUICK
    timings, efficiencies = bench.run_benchmark(
        quick["sizes"],
        naive_points=quick["naive_points"],
        repeats=quick["repeats"],
        efficiency_points=quick["efficiency_points"],
        out_dir=out,
        log=lambda *args: None,
    )
    return timings, efficiencies, out


def test_quick_mode_methods_agree(bench, quick_run):
    timings, _, _ = quick_run
    assert {row["n_points"] for row in timings} == set(bench.QUICK["sizes"])
    for n_points in bench.QUICK["sizes"]:
        methods = {row["method"] for row in timings if row["n_points"] == n_points}
        assert methods == set(bench.METHODS)
    for row in timings:
        assert row["agree"] is True, row
        assert row["light_diff_deg"] < bench.LIGHT_TOLERANCE_DEG
        assert row["albedo_max_diff"] < bench.PARAMETER_TOLERANCE and row["k_max_diff"] < bench.PARAMETER_TOLERANCE
        # Noiseless: every method also finds the truth.
        assert row["light_err_truth_deg"] < bench.LIGHT_TOLERANCE_DEG
        assert row["seconds"] > 0 and row["peak_mib"] >= 0
    naive = [row for row in timings if row["method"] == "naive"]
    assert all("EXTRAPOLATED" in row["note"] for row in naive)


def test_quick_mode_efficiency_and_files(quick_run):
    _, efficiencies, out = quick_run
    assert len(efficiencies) == 3
    for row in efficiencies:
        assert row["albedo_efficiency"] > 0.8 and row["k_efficiency"] > 0.8, row
        assert row["light_mahalanobis"] < 3.5, row
    for name in ("timings.csv", "efficiency.csv", "timings.png", "summary.txt"):
        assert (out / name).stat().st_size > 0
    with open(out / "timings.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 8 and {"method", "seconds", "x_varpro", "peak_mib", "agree"} <= set(rows[0])
    assert "agree" in (out / "summary.txt").read_text()


def test_naive_solver_on_a_few_points(bench):
    obs, albedo, k = bench.make_observations(5, 12, seed=3)
    light, albedo_fit, k_fit, n_evaluations = bench.fit_naive(obs)
    assert np.degrees(np.arccos(np.clip(light @ bench.true_light(), -1, 1))) < 1e-4
    assert np.allclose(albedo_fit, albedo, atol=1e-6) and np.allclose(k_fit, k, atol=1e-6)
    assert n_evaluations > 20


def test_blur_matrix_bench_assemblies_give_the_same_products(capsys):
    spec = importlib.util.spec_from_file_location("bench_blur_matrix", BENCH.parent / "bench_blur_matrix.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    ratio, same = module.main(["--radius", "20", "--repeats", "1"])
    assert same and ratio > 0
    assert "products the same to the last bit: True" in capsys.readouterr().out


def test_shot_noise_bench_keeps_the_inverse_cdf_counts(capsys):
    spec = importlib.util.spec_from_file_location("bench_shot_noise", BENCH.parent / "bench_shot_noise.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    ratio, changed = module.main(["--images", "2", "--repeats", "1"])
    assert ratio > 0 and max(changed["inverse_cdf"]) < 1e-3
    assert "inverse_cdf" in capsys.readouterr().out


def test_mesh_step_bench_assemblies_and_solvers_agree():
    """bench/bench_mesh_step.py on a small sphere: scipy's J'J and the fit's assembly give the same matrix, and the two
    solvers the same step."""
    spec = importlib.util.spec_from_file_location("bench_mesh_step", BENCH.parent / "bench_mesh_step.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    _, steps_apart, _, matrices_apart = module.main(["--subdivisions", "3", "--repeats", "1"])
    assert matrices_apart < 1e-12
    assert steps_apart < 1e-8
