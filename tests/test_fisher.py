"""Tests of the Fisher information and Cramer-Rao bounds (asteroid_photometry.estimation.fisher)."""

import numpy as np
import pytest

from asteroid_photometry.estimation import (
    fisher,
    fit_koizumi_lm,
    light_from_tangent,
    Observations,
    synthetic_observations,
    tangent_from_light,
)
from asteroid_photometry.estimation.fisher import cramer_rao_bounds, efficiency, fisher_blocks
from asteroid_photometry.estimation.varpro import fit_varpro
from asteroid_photometry.reflectance.laws import minnaert_brightness
from asteroid_photometry.world import noise
from synthetic_helpers import light_at, per_point_truth




def model(obs, parameters):
    """Minnaert brightness of every observation for x = [a, b, albedo_0, k_0, albedo_1, k_1, ...]."""
    light = light_from_tangent(parameters[:2])
    albedo, k = parameters[2::2], parameters[3::2]
    return minnaert_brightness(albedo[obs.point_index], k[obs.point_index], obs.cos_incidence(light), obs.cos_emission)


@pytest.fixture(scope="module")
def small_problem():
    light = light_at(10.0)
    albedo, k = per_point_truth(6, seed=1)
    obs = synthetic_observations(6, 9, light, albedo, k, np.random.default_rng(2))
    truth = np.concatenate([tangent_from_light(light), np.column_stack([albedo, k]).ravel()])
    variance = np.random.default_rng(3).uniform(1e-5, 4e-5, obs.n_obs)  # heteroscedastic
    return obs, light, albedo, k, truth, variance


def test_fisher_information_is_jtwj_of_the_numerical_jacobian(small_problem):
    obs, light, albedo, k, truth, variance = small_problem
    step = 1e-6
    jacobian = np.empty((obs.n_obs, truth.size))
    for column in range(truth.size):
        delta = np.zeros_like(truth)
        delta[column] = step
        jacobian[:, column] = (model(obs, truth + delta) - model(obs, truth - delta)) / (2 * step)
    expected = jacobian.T @ (jacobian / variance[:, None])
    blocks = fisher_blocks(obs, light, albedo, k, variance)
    assert blocks.included.all() and blocks.n_obs == obs.n_obs
    assert np.allclose(blocks.dense(), expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max())


def test_fisher_information_is_the_hessian_of_the_negative_log_likelihood(small_problem):
    # At the truth with noiseless data the residuals vanish, so the Hessian of
    # -log L = 0.5 sum (b - f)^2 / var is exactly the Fisher information.
    obs, light, albedo, k, truth, variance = small_problem
    observed = model(obs, truth)

    def negative_log_likelihood(parameters):
        return 0.5 * np.sum((observed - model(obs, parameters)) ** 2 / variance)

    step = 1e-4
    n = truth.size
    hessian = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            ei, ej = np.eye(n)[i] * step, np.eye(n)[j] * step
            hessian[i, j] = (
                negative_log_likelihood(truth + ei + ej)
                - negative_log_likelihood(truth + ei - ej)
                - negative_log_likelihood(truth - ei + ej)
                + negative_log_likelihood(truth - ei - ej)
            ) / (4 * step * step)
    information = fisher_blocks(obs, light, albedo, k, variance).dense()
    assert np.allclose(information, hessian, rtol=1e-4, atol=1e-5 * np.abs(information).max())


def test_bounds_are_the_inverse_of_the_dense_information(small_problem):
    obs, light, albedo, k, truth, variance = small_problem
    inverse = np.linalg.inv(fisher_blocks(obs, light, albedo, k, variance).dense())
    bounds = cramer_rao_bounds(obs, light, albedo, k, variance)
    assert np.allclose(bounds["light_cov"], inverse[:2, :2], rtol=1e-9)
    assert np.allclose(bounds["albedo_var"], inverse.diagonal()[2::2], rtol=1e-9)
    assert np.allclose(bounds["k_var"], inverse.diagonal()[3::2], rtol=1e-9)
    assert np.allclose(bounds["albedo_k_cov"], [inverse[2 + 2 * p, 3 + 2 * p] for p in range(6)], rtol=1e-9)
    assert bounds["light_std_deg"] > 0


def test_geometry_input_callable_variance_and_left_out_points():
    light = light_at(10.0)
    albedo, k = per_point_truth(40, seed=4)
    obs = synthetic_observations(40, 8, light, albedo, k, np.random.default_rng(5))
    # Point 40 seen once: left out.
    geometry = dict(
        point_index=np.concatenate([obs.point_index, [40]]),
        normal_cam=np.vstack([obs.normal_cam, obs.normal_cam[:1]]),
        view_cam=np.vstack([obs.view_cam, obs.view_cam[:1]]),
        n_points=41,
    )
    sensor = noise.sensor_from_config(noise.PROPOSED_NOISE_LEVELS[1])
    albedo41, k41 = np.append(albedo, 0.5), np.append(k, 0.8)
    with_callable = cramer_rao_bounds(geometry, light, albedo41, k41, lambda b: noise.observation_variance(b, sensor))
    padded = Observations(geometry["point_index"], geometry["normal_cam"], geometry["view_cam"], np.zeros(obs.n_obs + 1), 41)
    truth = minnaert_brightness(albedo41[padded.point_index], k41[padded.point_index], padded.cos_incidence(light), padded.cos_emission)
    with_array = cramer_rao_bounds(padded, light, albedo41, k41, noise.observation_variance(truth, sensor))
    assert np.isnan(with_callable["albedo_var"][40]) and np.all(np.isfinite(with_callable["albedo_var"][:40]))
    assert np.allclose(with_callable["k_var"][:40], with_array["k_var"][:40], rtol=1e-12)
    assert np.allclose(with_callable["light_cov"], with_array["light_cov"], rtol=1e-12)
    # A scalar variance scales every bound.
    one = cramer_rao_bounds(obs, light, albedo, k, 1e-4)
    four = cramer_rao_bounds(obs, light, albedo, k, 4e-4)
    assert np.allclose(four["k_var"], 4 * one["k_var"]) and four["light_std_deg"] == pytest.approx(2 * one["light_std_deg"])


def test_fisher_rejects_bad_input():
    obs = synthetic_observations(10, 6, light_at(0.0), 0.5, 0.8, np.random.default_rng(0))
    with pytest.raises(ValueError, match="variance must be finite"):
        fisher_blocks(obs, light_at(0.0), 0.5, 0.8, 0.0)
    with pytest.raises(ValueError, match="variance must be a scalar"):
        fisher_blocks(obs, light_at(0.0), 0.5, 0.8, np.ones(3))
    with pytest.raises(ValueError, match="albedo must be a scalar"):
        fisher_blocks(obs, light_at(0.0), np.ones(3), 0.8, 1e-4)
    with pytest.raises(ValueError, match="geometry with point_index"):
        fisher_blocks({"point_index": obs.point_index}, light_at(0.0), 0.5, 0.8, 1e-4)


def test_efficiency_arithmetic():
    bounds = {"albedo_var": np.array([1.0, 4.0]), "k_var": np.array([1.0, 1.0]), "light_cov": np.eye(2) * 1e-6}
    bounds["light_std_deg"] = float(np.degrees(np.sqrt(2e-6)))
    light = light_from_tangent([0.0, 0.0])
    estimate = {"light_dir_cam": light_from_tangent([1e-3, 0.0]), "albedo": np.array([1.0, 2.0]), "minnaert_k": np.array([0.5, 1.5])}
    truth = (light, np.array([0.0, 0.0]), np.array([0.0, 0.0]))
    result = efficiency(estimate, truth, bounds)
    assert result["albedo_efficiency"] == pytest.approx(1.0)  # errors 1 and 2 against std 1 and 2
    assert result["k_efficiency"] == pytest.approx(1.0 / 1.25)
    assert result["light_mahalanobis"] == pytest.approx(1.0, rel=1e-6)
    assert result["light_error_sigma"] == pytest.approx(1.0 / np.sqrt(2.0), rel=1e-5)
    assert result["n_points"] == 2


# --------------------------------------------------------------------------
# The estimators reach the bound
# --------------------------------------------------------------------------


def test_estimators_are_efficient_on_noisy_data():
    light = light_at(10.0)
    albedo, k = per_point_truth(3000, seed=60)
    sigma = 0.01
    obs = synthetic_observations(3000, 16, light, albedo, k, np.random.default_rng(61), noise_sigma=sigma)
    bounds = cramer_rao_bounds(obs, light, albedo, k, sigma**2)
    for result in (fit_varpro(obs, sigma=sigma), fit_koizumi_lm(obs)):
        scores = efficiency(result, (light, albedo, k), bounds)
        assert scores["n_points"] == 3000
        assert scores["albedo_efficiency"] >= 0.8, (result.method, scores)
        assert scores["k_efficiency"] >= 0.8, (result.method, scores)
        assert scores["light_error_sigma"] < 3.0 and scores["light_mahalanobis"] < 3.5, (result.method, scores)


def test_varpro_is_efficient_under_the_sensor_noise_model():
    # Heteroscedastic noise: the underexposed AMICA-like camera (3.6 % at b = 0.35).
    sensor = noise.sensor_from_config(noise.PROPOSED_NOISE_LEVELS[2])
    light = light_at(10.0)
    albedo, k = per_point_truth(2000, seed=62)
    clean = synthetic_observations(2000, 24, light, albedo, k, np.random.default_rng(63))
    variance = noise.observation_variance(clean.brightness, sensor)
    noisy = np.random.default_rng(64).normal(clean.brightness, np.sqrt(variance))
    obs = Observations(clean.point_index, clean.normal_cam, clean.view_cam, noisy, clean.n_points)
    # The estimator weights by the variance at the *observed* brightness, as it would in practice.
    result = fit_varpro(obs, sigma=np.sqrt(noise.observation_variance(np.clip(noisy, 1e-3, None), sensor)))
    bounds = cramer_rao_bounds(clean, light, albedo, k, lambda b: noise.observation_variance(b, sensor))
    scores = efficiency(result, (light, albedo, k), bounds)
    assert scores["albedo_efficiency"] >= 0.8 and scores["k_efficiency"] >= 0.8, scores
    assert scores["light_error_sigma"] < 3.0, scores
    # The estimator's own uncertainty agrees with the bound.
    assert np.median(result.minnaert_k_std**2 / bounds["k_var"]) == pytest.approx(1.0, abs=0.1)
    assert result.light_std_deg == pytest.approx(bounds["light_std_deg"], rel=0.1)


def test_module_exports_exist():
    for name in fisher.__all__:
        assert hasattr(fisher, name)


def test_table2s_light_bound_follows_the_mission_sensor_and_is_absent_without_one():
    """Table 2's Cramer-Rao deviation of the light: from the mission's sensor model alone; ten times the electrons, about a third of it."""
    from types import SimpleNamespace

    from asteroid_photometry.estimation.registry import run_estimator
    from asteroid_photometry.experiments.table2 import light_bound_deg

    obs = synthetic_observations(300, 10, light_at(10.0), 0.5, 0.8, np.random.default_rng(3))
    fit = run_estimator(obs, "koizumi_lm")
    settings = {"min_observations_per_point": 4}

    def stage(full_well_e):
        sensor = None if full_well_e is None else {
            "name": "test", "full_well_e": full_well_e, "read_noise_e": 0.0, "bit_depth": 16, "radiance_at_full_well": 1.0,
        }
        return SimpleNamespace(mission={"sensor": sensor}, pure=SimpleNamespace(observations=obs))

    coarse, fine = light_bound_deg(stage(30000.0), fit, settings), light_bound_deg(stage(300000.0), fit, settings)
    assert 0.0 < fine < coarse
    assert coarse / fine == pytest.approx(np.sqrt(10.0), rel=0.05)
    assert np.isnan(light_bound_deg(stage(None), fit, settings))


def test_table2s_light_bound_leaves_out_the_points_the_fit_left_out():
    """A point the final fit left out (``plausible_points``: NaN albedo and k) leaves the bound finite: the bound of
    the fit's other points' observations, exactly (before, one such point made the whole set's bound NaN)."""
    from dataclasses import replace
    from types import SimpleNamespace

    from asteroid_photometry.estimation.registry import run_estimator
    from asteroid_photometry.experiments.table2 import light_bound_deg

    obs = synthetic_observations(300, 10, light_at(10.0), 0.5, 0.8, np.random.default_rng(5))
    fit = run_estimator(obs, "koizumi_lm")
    settings = {"min_observations_per_point": 4}
    sensor = {"name": "test", "full_well_e": 30000.0, "read_noise_e": 0.0, "bit_depth": 16, "radiance_at_full_well": 1.0}
    dropped = 7
    albedo, minnaert_k = fit.albedo.copy(), fit.minnaert_k.copy()
    albedo[dropped] = minnaert_k[dropped] = np.nan
    partial = replace(fit, albedo=albedo, minnaert_k=minnaert_k)
    bound = light_bound_deg(SimpleNamespace(mission={"sensor": sensor}, pure=SimpleNamespace(observations=obs)), partial, settings)
    others = obs.rows(obs.point_index != dropped)
    expected = light_bound_deg(SimpleNamespace(mission={"sensor": sensor}, pure=SimpleNamespace(observations=others)), partial, settings)
    assert np.isfinite(bound) and bound > 0
    assert bound == pytest.approx(expected, rel=1e-12)
    # Leaving a point out loses information: the bound of all points' fit is smaller.
    assert light_bound_deg(SimpleNamespace(mission={"sensor": sensor}, pure=SimpleNamespace(observations=obs)), fit, settings) < bound


def test_table2s_light_bound_is_raised_only_where_the_noise_allows_less():
    """light_err_over_bound_final: the error over the condition's bound, or over three Cramer-Rao deviations if that is larger."""
    import pandas as pd

    from asteroid_photometry.experiments.table2_scoring import light_err_over_bound

    table = pd.DataFrame({
        "imaging": ["amica", "amica", "ideal", "amica"],
        "light_dir_err_deg_final": [1.3, 1.3, 0.4, -0.5],
        "light_crb_deg_final": [0.5, 0.2, np.nan, np.nan],
    })
    assert light_err_over_bound(table).tolist() == pytest.approx([1.3 / 1.5, 1.3, 0.8, 0.5])
