"""Tests of the estimators (asteroid_photometry.estimation) on synthetic observations."""

import numpy as np
import pytest

from asteroid_photometry import estimation
from asteroid_photometry.estimation import (
    angle_between_deg,
    fit_iwano_linear,
    fit_koizumi_lm,
    fit_pooled_k,
    initial_albedo_and_k,
    KoizumiProblem,
    light_angle_deg,
    light_from_tangent,
    Observations,
    synthetic_observations,
    tangent_from_light,
)
from asteroid_photometry.evaluation import metrics
from synthetic_helpers import light_at, per_point_truth




# --------------------------------------------------------------------------
# Light parameterisation and angles
# --------------------------------------------------------------------------


def test_tangent_round_trip_including_light_angle_zero():
    assert np.array_equal(tangent_from_light([0.0, 0.0, -1.0]), [0.0, 0.0])
    assert np.allclose(light_from_tangent([0.0, 0.0]), [0.0, 0.0, -1.0], atol=0, rtol=0)
    assert light_angle_deg(light_from_tangent([0.0, 0.0])) == 0.0

    rng = np.random.default_rng(0)
    tangents = rng.normal(0.0, 0.3, (100, 2))
    tangents[0] = [1e-12, -3e-13]  # a light angle of about 6e-11 deg
    lights = light_from_tangent(tangents)
    assert np.allclose(np.linalg.norm(lights, axis=1), 1.0, atol=1e-15)
    assert np.allclose(tangent_from_light(lights), tangents, rtol=1e-13, atol=1e-25)
    # The tangent's length is tan(light angle).
    assert np.allclose(np.radians(light_angle_deg(lights)), np.arctan(np.hypot(*tangents.T)), rtol=1e-12, atol=1e-25)
    for angle in (0.0, 10.0, 60.0):
        assert light_angle_deg(light_from_tangent(tangent_from_light(light_at(angle)))) == pytest.approx(
            angle, abs=1e-12
        )


@pytest.mark.parametrize("light", [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.1, 0.2, 0.5]])
def test_tangent_from_light_rejects_the_far_hemisphere(light):
    with pytest.raises(ValueError, match="l_z < 0"):
        tangent_from_light(light)


def test_angle_between_is_accurate_for_tiny_and_straight_angles():
    tiny = 1e-9  # radians; arccos of the dot product would return 0 here
    assert angle_between_deg([0.0, 0.0, -1.0], [np.sin(tiny), 0.0, -np.cos(tiny)]) == pytest.approx(
        np.degrees(tiny), rel=1e-9
    )
    assert angle_between_deg([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]) == pytest.approx(180.0)
    assert angle_between_deg([2.0, 0.0, 0.0], [0.0, 0.0, 5.0]) == pytest.approx(90.0)
    assert light_angle_deg(light_at(10.0)) == pytest.approx(10.0, abs=1e-12)


# --------------------------------------------------------------------------
# Observations
# --------------------------------------------------------------------------


def small_arrays():
    normal = np.array([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8], [0.0, 0.6, -0.8]])
    view = np.array([[0.0, 0.0, -1.0]] * 3)
    return dict(
        point_index=np.array([0, 1, 1]), normal_cam=normal, view_cam=view, brightness=np.array([0.5, 0.4, 0.3]), n_points=3
    )


def test_observations_are_copied_read_only_and_derive_cos_emission():
    arrays = small_arrays()
    obs = Observations(**arrays)
    assert obs.point_index.dtype == np.int64 and obs.normal_cam.dtype == np.float64
    assert np.allclose(obs.cos_emission, [1.0, 0.8, 0.8])
    assert obs.n_obs == 3 and list(obs.observations_per_point) == [1, 2, 0]
    assert np.allclose(obs.point_means(obs.brightness), [0.5, 0.35, 0.0])
    assert np.allclose(obs.point_means(obs.view_cam)[1], obs.view_cam[1:].mean(axis=0)) and obs.point_means(obs.view_cam).shape == (3, 3)
    with pytest.raises(ValueError):
        obs.brightness[0] = 1.0
    arrays["brightness"][0] = 9.0  # the caller's array is not shared
    assert obs.brightness[0] == 0.5


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(normal_cam=np.ones((3, 2))), r"normal_cam must have shape \(3, 3\)"),
        (dict(view_cam=np.zeros((2, 3))), r"view_cam must have shape \(3, 3\)"),
        (dict(brightness=np.ones(4)), r"brightness must have shape \(3,\)"),
        (dict(point_index=np.zeros((3, 1), int)), r"point_index must have shape \(n_obs,\)"),
        (dict(brightness=np.array([0.5, np.nan, 0.3])), "brightness has 1 non-finite"),
        (dict(normal_cam=np.array([[0.0, 0.0, -1.0], [0.6, 0.0, -0.8], [0.0, 0.6, -0.81]])), "unit vectors"),
        (dict(view_cam=np.array([[0.0, 0.0, -1.0]] * 2 + [[0.0, 0.0, -1.00001]])), "view_cam must hold unit"),
        (dict(point_index=np.array([0, 1, 3])), r"point_index must lie in \[0, 3\)"),
        (dict(point_index=np.array([0, -1, 1])), r"point_index must lie in \[0, 3\)"),
        (dict(point_index=np.array([0.0, 1.0, 1.0])), "point_index must be integers"),
        (dict(n_points=2.0), "n_points must be an int"),
        (dict(n_points=-1), "n_points must be >= 0"),
        (dict(view_cam=np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])), "cos_emission > 0"),
    ],
)
def test_observations_validation(change, message):
    arrays = small_arrays()
    arrays.update(change)
    with pytest.raises(ValueError, match=message):
        Observations(**arrays)


def test_synthetic_observations_are_deterministic_and_within_limits():
    light = light_at(10.0)
    first = synthetic_observations(200, 10, light, 0.6, 0.8, np.random.default_rng(5))
    second = synthetic_observations(200, 10, light, 0.6, 0.8, np.random.default_rng(5))
    assert np.array_equal(first.normal_cam, second.normal_cam)
    assert np.array_equal(first.brightness, second.brightness)
    assert np.all(first.cos_incidence(light) > 0.1) and np.all(first.cos_emission > 0.1)
    per_point = first.observations_per_point
    assert per_point.max() <= 10 and np.mean(per_point) > 9.0
    # Slight perspective: the view vectors are close to, but not exactly, -z.
    view_angle = light_angle_deg(first.view_cam)
    assert 0.5 < view_angle.max() < 4.0
    # Variety in cos_i against cos_o within points, so that k is identifiable.
    log_sum = np.log(first.cos_incidence(light) * first.cos_emission)
    spread = np.bincount(first.point_index, log_sum**2, 200) / per_point - (
        np.bincount(first.point_index, log_sum, 200) / per_point
    ) ** 2
    assert np.min(spread) > 1e-2


# --------------------------------------------------------------------------
# The joint fit's Jacobian and initialisation
# --------------------------------------------------------------------------


@pytest.mark.parametrize("angle_deg", [0.0, 10.0])
def test_jacobian_matches_finite_differences(angle_deg):
    albedo, k = per_point_truth(25, seed=1)
    obs = synthetic_observations(25, 6, light_at(angle_deg), albedo, k, np.random.default_rng(2))
    problem = KoizumiProblem(obs)
    rng = np.random.default_rng(3)
    x = problem.pack(tangent_from_light(light_at(angle_deg + 1.0, 80.0)), albedo * 1.1, k - 0.05)
    x = x + rng.normal(0.0, 1e-3, x.shape)
    jacobian = problem.jacobian(x).toarray()
    assert jacobian.shape == (obs.n_obs, 2 + 2 * 25)
    step = 1e-6
    numeric = np.empty_like(jacobian)
    for column in range(x.size):
        delta = np.zeros_like(x)
        delta[column] = step
        numeric[:, column] = (problem.residuals(x + delta) - problem.residuals(x - delta)) / (2 * step)
    assert np.allclose(jacobian, numeric, rtol=1e-6, atol=1e-9)


def test_initial_albedo_and_k_is_exact_for_the_true_light_and_handles_singular_points():
    light = light_at(10.0)
    albedo, k = per_point_truth(50, seed=4)
    obs = synthetic_observations(50, 8, light, albedo, k, np.random.default_rng(4))
    # Add point 50: every observation with the same geometry, so k is undetermined.
    n = np.array([0.0, 0.0, -1.0])
    singular = Observations(
        point_index=np.concatenate([obs.point_index, [50, 50, 50]]),
        normal_cam=np.vstack([obs.normal_cam, [n, n, n]]),
        view_cam=np.vstack([obs.view_cam, [n, n, n]]),
        brightness=np.concatenate([obs.brightness, [0.4, 0.4, 0.4]]),
        n_points=51,
    )
    init_albedo, init_k = initial_albedo_and_k(KoizumiProblem(singular), light)
    assert np.allclose(init_albedo[:50], albedo, rtol=1e-10)
    assert np.allclose(init_k[:50], k, atol=1e-10)
    assert init_k[50] == 1.0
    assert init_albedo[50] == pytest.approx(np.mean(init_albedo[:50]))


# --------------------------------------------------------------------------
# Noiseless recovery
# --------------------------------------------------------------------------


@pytest.mark.parametrize("angle_deg", [0.0, 10.0])
@pytest.mark.parametrize("solver", ["block_lm", "least_squares"])
@pytest.mark.parametrize("light_init", [None, "iwano", "off_by_5_deg"])
def test_koizumi_lm_recovers_noiseless_truth(angle_deg, solver, light_init):
    light = light_at(angle_deg)
    albedo, k = per_point_truth(400, seed=10)
    obs = synthetic_observations(400, 12, light, albedo, k, np.random.default_rng(11))
    if light_init == "off_by_5_deg":
        light_init = light_from_tangent(tangent_from_light(light) + np.tan(np.radians(5.0)) * np.array([0.6, -0.8]))
    result = fit_koizumi_lm(obs, light_init=light_init, solver=solver)
    assert result.success, result.message
    assert result.method == "koizumi_lm" and result.n_points_fitted == 400 and result.n_obs == obs.n_obs
    assert angle_between_deg(result.light_dir_cam, light) < 1e-4
    assert np.max(np.abs(result.albedo - albedo)) < 1e-6
    assert np.max(np.abs(result.minnaert_k - k)) < 1e-6
    assert result.cost < 1e-20
    assert result.fit_seconds > 0 and result.nfev >= 1
    assert result.light_angle_deg == pytest.approx(angle_deg, abs=1e-4)


def test_koizumi_lm_from_a_given_light_init():
    light = light_at(10.0)
    albedo, k = per_point_truth(300, seed=12)
    obs = synthetic_observations(300, 10, light, albedo, k, np.random.default_rng(13))
    result = fit_koizumi_lm(obs, light_init=light_at(3.0, 200.0))
    assert angle_between_deg(result.light_dir_cam, light) < 1e-4
    assert np.max(np.abs(result.minnaert_k - k)) < 1e-6


def test_koizumi_lm_holding_the_light_fits_only_the_points():
    light = light_at(10.0)
    albedo, k = per_point_truth(300, seed=14)
    obs = synthetic_observations(300, 10, light, albedo, k, np.random.default_rng(15))
    held = fit_koizumi_lm(obs, light_init=light, hold_light=True)
    assert angle_between_deg(held.light_dir_cam, light) < 1e-12
    assert np.max(np.abs(held.albedo - albedo)) < 1e-9 and np.max(np.abs(held.minnaert_k - k)) < 1e-9
    # Held at a wrong light the points cannot explain the brightness; free, the fit leaves that light.
    wrong = light_at(11.0)
    held_wrong = fit_koizumi_lm(obs, light_init=wrong, hold_light=True)
    assert angle_between_deg(held_wrong.light_dir_cam, wrong) < 1e-12 and held_wrong.cost > 1e-8
    assert angle_between_deg(fit_koizumi_lm(obs, light_init=wrong).light_dir_cam, light) < 1e-4
    for bad in ({"light_init": None}, {"light_init": "iwano"}, {"light_init": light, "solver": "least_squares"}):
        with pytest.raises(ValueError, match="hold_light needs"):
            fit_koizumi_lm(obs, hold_light=True, **bad)


def test_pooled_k_recovers_noiseless_truth_from_a_poor_start():
    light = light_at(10.0)
    albedo, _ = per_point_truth(300, seed=16)
    obs = synthetic_observations(300, 10, light, albedo, 0.8, np.random.default_rng(17))
    result = fit_pooled_k(obs, light_at(3.0, 200.0), 1.0)
    assert result.success and result.method == "pooled_k" and result.n_points_fitted == 300
    assert angle_between_deg(result.light_dir_cam, light) < 1e-6
    assert np.max(np.abs(result.albedo - albedo)) < 1e-8 and np.max(np.abs(result.minnaert_k - 0.8)) < 1e-8
    with pytest.raises(ValueError, match="minnaert_k_init must be a positive"):
        fit_pooled_k(obs, light, 0.0)
    with pytest.raises(ValueError, match="light_init must be a finite"):
        fit_pooled_k(obs, [np.nan, 0.0, -1.0], 0.8)
    empty = Observations(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 4)
    with pytest.raises(ValueError, match="cannot determine"):
        fit_pooled_k(empty, light, 0.8)


def test_one_k_holds_the_light_out_of_the_plane_of_the_views():
    # A per-point k takes up, to second order, what a tilt of the light out of the plane of the views
    # and the Sun does to each point (estimation.fit_pooled_k): under noise the joint fit's light
    # wanders in elevation several times more than with one k, while its azimuth is as well held.
    light = light_at(10.0, 0.0)
    spin_axis = [0.0, 1.0, 0.0]  # synthetic_observations turns the body about the camera's y axis
    joint, pooled = [], []
    for seed in range(8):
        obs = synthetic_observations(300, 6, light, 0.6, 0.8, np.random.default_rng(50 + seed), noise_sigma=1e-3)
        joint.append(metrics.light_error_components_deg(fit_koizumi_lm(obs, light_init=light).light_dir_cam, light, spin_axis))
        pooled.append(metrics.light_error_components_deg(fit_pooled_k(obs, light, 1.0).light_dir_cam, light, spin_axis))
    (joint_azimuth, joint_elevation), (pooled_azimuth, pooled_elevation) = np.sqrt(np.mean(np.square(joint), 0)), np.sqrt(np.mean(np.square(pooled), 0))
    assert joint_elevation > 2.0 * pooled_elevation
    assert 0.7 < joint_azimuth / pooled_azimuth < 1.5
    assert joint_elevation > 3.0 * joint_azimuth


@pytest.mark.parametrize("angle_deg", [0.0, 10.0])
@pytest.mark.parametrize("true_k", [0.7, 1.0])
def test_iwano_recovers_noiseless_truth_with_the_right_k(angle_deg, true_k):
    light = light_at(angle_deg)
    obs = synthetic_observations(500, 12, light, 0.6, true_k, np.random.default_rng(20))
    result = fit_iwano_linear(obs, true_k)
    assert result.method == "iwano_linear" and result.success
    assert angle_between_deg(result.light_dir_cam, light) < 1e-4
    assert np.allclose(result.albedo, 0.6, rtol=1e-6)
    assert np.all(result.minnaert_k == true_k)
    assert result.cost < 1e-20


def test_iwano_is_biased_when_k_is_wrong():
    light = light_at(10.0)
    obs = synthetic_observations(500, 12, light, 0.6, 0.7, np.random.default_rng(21))
    wrong = fit_iwano_linear(obs, 1.0)
    assert angle_between_deg(wrong.light_dir_cam, light) > 0.5
    assert abs(wrong.albedo[0] / 0.6 - 1.0) > 0.01
    assert wrong.cost > 1e-4
    # The joint fit, which estimates k, is not fooled by the same data.
    joint = fit_koizumi_lm(obs)
    assert angle_between_deg(joint.light_dir_cam, light) < 1e-4


def test_points_without_observations_are_nan():
    light = light_at(10.0)
    obs = synthetic_observations(100, 8, light, 0.5, 0.8, np.random.default_rng(30))
    # Points 100 and 101 are never observed; point 102 is seen once (too few for albedo and k).
    keep_one = obs.point_index == 0
    row = np.flatnonzero(keep_one)[0]
    padded = Observations(
        point_index=np.concatenate([obs.point_index, [102]]),
        normal_cam=np.vstack([obs.normal_cam, obs.normal_cam[row]]),
        view_cam=np.vstack([obs.view_cam, obs.view_cam[row]]),
        brightness=np.concatenate([obs.brightness, obs.brightness[row : row + 1]]),
        n_points=103,
    )
    joint = fit_koizumi_lm(padded)
    assert joint.albedo.shape == (103,) and joint.n_points_fitted == 100
    assert np.all(np.isnan(joint.albedo[100:])) and np.all(np.isnan(joint.minnaert_k[100:]))
    assert np.all(np.isfinite(joint.albedo[:100]))
    assert np.allclose(joint.albedo[:100], 0.5, atol=1e-6)

    iwano = fit_iwano_linear(padded, 0.8)
    assert np.all(np.isnan(iwano.albedo[100:102])) and np.all(np.isnan(iwano.minnaert_k[100:102]))
    assert np.allclose(iwano.albedo[[0, 50, 102]], 0.5, rtol=1e-6)


def test_estimators_reject_unusable_input():
    empty = Observations(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 4)
    with pytest.raises(ValueError, match="at least 3 observations"):
        fit_iwano_linear(empty, 0.8)
    with pytest.raises(ValueError, match="cannot determine"):
        fit_koizumi_lm(empty)
    obs = synthetic_observations(20, 6, light_at(0.0), 0.5, 0.8, np.random.default_rng(0))
    with pytest.raises(ValueError, match="solver must be one of"):
        fit_koizumi_lm(obs, solver="dense")
    with pytest.raises(ValueError, match="minnaert_k must be a positive"):
        fit_iwano_linear(obs, 0.0)
    with pytest.raises(ValueError, match="l_z < 0"):
        fit_koizumi_lm(obs, light_init=[0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="light_init must be"):
        fit_koizumi_lm(obs, light_init="lambert")


# --------------------------------------------------------------------------
# Noisy data
# --------------------------------------------------------------------------


def noisy_errors(n_views, seed):
    light = light_at(10.0)
    albedo, k = per_point_truth(600, seed=seed)
    obs = synthetic_observations(600, n_views, light, albedo, k, np.random.default_rng(seed), noise_sigma=0.01)
    result = fit_koizumi_lm(obs)
    assert result.success, result.message
    return (
        angle_between_deg(result.light_dir_cam, light),
        np.sqrt(np.mean((result.albedo - albedo) ** 2)),
        np.sqrt(np.mean((result.minnaert_k - k) ** 2)),
    )


def test_noisy_errors_shrink_with_more_views():
    few = noisy_errors(6, seed=40)
    many = noisy_errors(24, seed=40)
    # Four times the views: per-point errors should about halve (1/sqrt(n)).
    assert many[1] < 0.7 * few[1]
    assert many[2] < 0.7 * few[2]
    assert many[0] < few[0]
    # The light uses every observation: its error stays well below a degree.
    assert few[0] < 1.0 and many[0] < 0.3
    # Sanity: noise does show up in the estimates.
    assert few[2] > 1e-3 and many[0] > 1e-3


def test_light_search_escapes_the_local_minimum_of_the_iwano_start():
    # Albedo varying per point, 6 views, noise: Iwano's single-albedo guess is ~17 deg
    # off along the spin axis and LM started there stops in a local minimum.
    light = light_at(10.0)
    albedo, k = per_point_truth(600, seed=40)
    obs = synthetic_observations(600, 6, light, albedo, k, np.random.default_rng(40), noise_sigma=0.01)
    from_iwano = fit_koizumi_lm(obs, light_init="iwano")
    searched = fit_koizumi_lm(obs)
    from_truth = fit_koizumi_lm(obs, light_init=light)
    assert angle_between_deg(from_iwano.light_dir_cam, light) > 5.0
    assert searched.cost == pytest.approx(from_truth.cost, rel=1e-9)
    assert searched.cost < 0.5 * from_iwano.cost
    assert angle_between_deg(searched.light_dir_cam, from_truth.light_dir_cam) < 1e-5


def test_solvers_agree_on_noisy_data():
    light = light_at(10.0)
    albedo, k = per_point_truth(300, seed=50)
    obs = synthetic_observations(300, 10, light, albedo, k, np.random.default_rng(50), noise_sigma=0.005)
    block = fit_koizumi_lm(obs, solver="block_lm")
    generic = fit_koizumi_lm(obs, solver="least_squares")
    assert block.cost == pytest.approx(generic.cost, rel=1e-10)
    assert angle_between_deg(block.light_dir_cam, generic.light_dir_cam) < 1e-6
    assert np.max(np.abs(block.minnaert_k - generic.minnaert_k)) < 1e-6
    assert np.max(np.abs(block.albedo - generic.albedo)) < 1e-6


def test_module_exports_exist():
    for name in estimation.__all__:
        assert hasattr(estimation, name)


def test_the_final_fit_sees_only_what_the_refinements_light_lights():
    """table2.lit_samples: rows below the incidence cut go, a point left with too few rows loses all, the numbering stays."""
    from asteroid_photometry.estimation import synthetic_observations
    from asteroid_photometry.experiments.table2 import lit_samples
    from synthetic_helpers import light_at

    light = light_at(20.0)
    obs = synthetic_observations(40, 8, light, 0.5, 0.8, np.random.default_rng(5))
    cos_i = obs.cos_incidence(light)
    kept = lit_samples(obs, light, 0.5, 6)
    assert kept.n_points == obs.n_points and np.all(kept.cos_incidence(light) >= 0.5)
    expected_rows = (cos_i >= 0.5) & (np.bincount(obs.point_index[cos_i >= 0.5], minlength=obs.n_points)[obs.point_index] >= 6)
    assert kept.n_obs == int(expected_rows.sum()) and 0 < kept.n_obs < obs.n_obs
    assert set(np.unique(kept.point_index)) == set(np.flatnonzero(np.bincount(kept.point_index, minlength=obs.n_points) >= 6))
    np.testing.assert_array_equal(kept.brightness, obs.brightness[expected_rows])
    assert lit_samples(obs, light, 0.0, 1).n_obs == obs.n_obs


def test_where_the_normals_tilted_freely_the_final_fit_keeps_the_well_lit_points():
    """table2.well_lit_points drops whole points by their rows' mean incidence cosine; final_observations applies it
    only to a refined cloud whose normals tilted freely."""
    from types import SimpleNamespace

    from asteroid_photometry.estimation import synthetic_observations
    from asteroid_photometry.experiments import table2
    from synthetic_helpers import light_at

    light = light_at(20.0)
    obs = synthetic_observations(60, 8, light, 0.5, 0.8, np.random.default_rng(6))
    cos_i = obs.cos_incidence(light)
    mean_cos = np.bincount(obs.point_index, weights=cos_i, minlength=obs.n_points) / np.bincount(obs.point_index, minlength=obs.n_points)
    cut = float(np.median(mean_cos))
    kept = table2.well_lit_points(obs, light, cut)
    # Every row of a point above the cut stays, its rows below the cut included; a point below it loses all.
    np.testing.assert_array_equal(kept.brightness, obs.brightness[mean_cos[obs.point_index] >= cut])
    assert kept.n_points == obs.n_points and 0 < kept.n_obs < obs.n_obs and np.any(kept.cos_incidence(light) < cut)

    settings = {"min_observations_per_point": 4}
    about_axis = SimpleNamespace(observations=obs, refined_light_dir_cam=light, normals_tilt_freely=False)
    lit_only = table2.lit_samples(obs, light, table2.FINAL_MIN_COS_INCIDENCE, 4)
    lit = table2.final_observations(SimpleNamespace(pure=about_axis), settings)
    expected = table2.seen_within_emission(lit_only, table2.FINAL_MIN_COS_EMISSION, 4)
    np.testing.assert_array_equal(lit.brightness, expected.brightness)
    free = table2.final_observations(SimpleNamespace(pure=SimpleNamespace(**{**vars(about_axis), "normals_tilt_freely": True})), settings)
    expected = table2.seen_within_emission(table2.well_lit_points(lit_only, light, table2.FREE_TILT_MIN_MEAN_COS_INCIDENCE), table2.FINAL_MIN_COS_EMISSION, 4)
    np.testing.assert_array_equal(free.brightness, expected.brightness)
    assert 0 < free.n_obs < lit.n_obs


def test_the_final_fit_leaves_out_the_samples_seen_near_the_limb():
    """table2.seen_within_emission drops the rows beyond the emission cut and the points left with too few rows;
    final_observations applies it with FINAL_MIN_COS_EMISSION, so no row it returns is seen more obliquely."""
    from types import SimpleNamespace

    from asteroid_photometry.estimation import synthetic_observations
    from asteroid_photometry.experiments import table2
    from synthetic_helpers import light_at

    light = light_at(20.0)
    obs = synthetic_observations(60, 8, light, 0.5, 0.8, np.random.default_rng(6))
    cut = table2.FINAL_MIN_COS_EMISSION
    assert np.any(obs.cos_emission < cut)
    squarely = obs.cos_emission >= cut
    per_point = np.bincount(obs.point_index[squarely], minlength=obs.n_points)
    expected_rows = squarely & (per_point[obs.point_index] >= 6)
    assert np.any(squarely & ~expected_rows)  # some point loses the rows it kept as well
    kept = table2.seen_within_emission(obs, cut, 6)
    np.testing.assert_array_equal(kept.brightness, obs.brightness[expected_rows])
    assert kept.n_points == obs.n_points

    final = table2.final_observations(SimpleNamespace(pure=SimpleNamespace(observations=obs, refined_light_dir_cam=light, normals_tilt_freely=False)), {"min_observations_per_point": 4})
    assert final.n_obs > 0 and final.cos_emission.min() >= cut
