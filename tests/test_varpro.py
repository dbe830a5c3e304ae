"""Tests of the variable-projection estimator (asteroid_photometry.estimation.varpro) and the arrow algebra it shares."""

import numpy as np
import pytest

from asteroid_photometry.estimation import (
    angle_between_deg,
    arrow_covariance,
    fit_koizumi_lm,
    FitResult,
    light_from_tangent,
    light_std_deg,
    Observations,
    solve_arrow_system,
    synthetic_observations,
    tangent_from_light,
    varpro,
)
from asteroid_photometry.estimation.varpro import fit_varpro, VarproResult
from synthetic_helpers import light_at, per_point_truth




def shuffled(obs, seed):
    order = np.random.default_rng(seed).permutation(obs.n_obs)
    return Observations(obs.point_index[order], obs.normal_cam[order], obs.view_cam[order], obs.brightness[order], obs.n_points)


# --------------------------------------------------------------------------
# Arrow algebra (estimate.solve_arrow_system, arrow_covariance, light_std_deg)
# --------------------------------------------------------------------------


def random_arrow(m, seed):
    """A random SPD arrow matrix, as blocks and as a dense matrix [a, b, p0_1, p0_2, p1_1, ...]."""
    rng = np.random.default_rng(seed)
    jacobian = np.zeros((6 * m, 2 + 2 * m))
    for p in range(m):
        jacobian[6 * p : 6 * p + 6, :2] = rng.normal(size=(6, 2))
        jacobian[6 * p : 6 * p + 6, 2 + 2 * p : 4 + 2 * p] = rng.normal(size=(6, 2))
    dense = jacobian.T @ jacobian
    u = dense[2::2, 2::2].diagonal(), np.array([dense[2 + 2 * p, 3 + 2 * p] for p in range(m)]), dense[3::2, 3::2].diagonal()
    w = dense[0, 2::2], dense[0, 3::2], dense[1, 2::2], dense[1, 3::2]
    v = dense[0, 0], dense[0, 1], dense[1, 1]
    return v, u, w, dense


def test_arrow_solve_and_covariance_match_dense_linear_algebra():
    v, u, w, dense = random_arrow(7, seed=0)
    gradient = np.random.default_rng(1).normal(size=dense.shape[0])
    step_light, step_1, step_2 = solve_arrow_system(v, u, w, tuple(gradient[:2]), (gradient[2::2], gradient[3::2]))
    expected = np.linalg.solve(dense, -gradient)
    assert np.allclose(step_light, expected[:2], rtol=1e-10, atol=1e-12)
    assert np.allclose(step_1, expected[2::2], rtol=1e-10, atol=1e-12)
    assert np.allclose(step_2, expected[3::2], rtol=1e-10, atol=1e-12)

    light_cov, var_1, var_2, cov_12 = arrow_covariance(v, u, w)
    inverse = np.linalg.inv(dense)
    assert np.allclose(light_cov, inverse[:2, :2], rtol=1e-10)
    assert np.allclose(var_1, inverse.diagonal()[2::2], rtol=1e-10)
    assert np.allclose(var_2, inverse.diagonal()[3::2], rtol=1e-10)
    assert np.allclose(cov_12, [inverse[2 + 2 * p, 3 + 2 * p] for p in range(7)], rtol=1e-10)


def test_light_std_deg_of_an_isotropic_tangent_covariance():
    # At the camera direction dl/d(a, b) is the identity: the RMS angle is sqrt(2) * s.
    s = 1e-4
    assert light_std_deg([0.0, 0.0], s * s * np.eye(2)) == pytest.approx(np.degrees(np.sqrt(2.0) * s), rel=1e-12)
    # Monte Carlo away from the axis: the mean squared angle matches.
    tangent = np.array([0.3, -0.2])
    cov = np.array([[4e-6, 1e-6], [1e-6, 2e-6]])
    draws = np.random.default_rng(2).multivariate_normal(tangent, cov, 20000)
    angles = angle_between_deg(light_from_tangent(draws), light_from_tangent(tangent))
    assert np.sqrt(np.mean(angles**2)) == pytest.approx(light_std_deg(tangent, cov), rel=0.02)


# --------------------------------------------------------------------------
# Noiseless recovery: the same answer as the paper's joint LM
# --------------------------------------------------------------------------


@pytest.mark.parametrize("angle_deg", [0.0, 10.0])
@pytest.mark.parametrize("light_init", [None, "iwano", "off_by_5_deg"])
def test_varpro_matches_the_joint_lm_on_noiseless_data(angle_deg, light_init):
    light = light_at(angle_deg)
    albedo, k = per_point_truth(2500, seed=10)
    obs = synthetic_observations(2500, 12, light, albedo, k, np.random.default_rng(11))
    if light_init == "off_by_5_deg":
        light_init = light_from_tangent(tangent_from_light(light) + np.tan(np.radians(5.0)) * np.array([0.6, -0.8]))
    result = fit_varpro(obs, light_init=light_init)
    joint = fit_koizumi_lm(obs)
    assert isinstance(result, VarproResult) and isinstance(result, FitResult)
    assert result.method == "varpro" and result.success, result.message
    assert result.n_points_fitted == 2500 and result.n_obs == obs.n_obs
    assert angle_between_deg(result.light_dir_cam, joint.light_dir_cam) < 1e-4
    assert np.max(np.abs(result.albedo - joint.albedo)) < 1e-5
    assert np.max(np.abs(result.minnaert_k - joint.minnaert_k)) < 1e-5
    # And both are the truth.
    assert angle_between_deg(result.light_dir_cam, light) < 1e-6
    assert np.max(np.abs(result.minnaert_k - k)) < 1e-8
    assert result.cost < 1e-20
    assert result.observation_used.all() and result.n_rejected == 0


def test_row_order_and_unfittable_points_do_not_matter():
    light = light_at(10.0)
    albedo, k = per_point_truth(300, seed=12)
    obs = synthetic_observations(300, 10, light, albedo, k, np.random.default_rng(13))
    # Point 300 never observed, point 301 seen once: both NaN.
    row = 0
    padded = Observations(
        point_index=np.concatenate([obs.point_index, [301]]),
        normal_cam=np.vstack([obs.normal_cam, obs.normal_cam[row]]),
        view_cam=np.vstack([obs.view_cam, obs.view_cam[row]]),
        brightness=np.concatenate([obs.brightness, obs.brightness[row : row + 1]]),
        n_points=302,
    )
    result = fit_varpro(shuffled(padded, seed=3))
    assert result.albedo.shape == (302,) and result.n_points_fitted == 300
    assert np.all(np.isnan(result.albedo[300:])) and np.all(np.isnan(result.albedo_std[300:]))
    assert np.max(np.abs(result.albedo[:300] - albedo)) < 1e-8
    assert angle_between_deg(result.light_dir_cam, light) < 1e-6
    assert result.n_obs == obs.n_obs


def test_polish_false_gives_the_log_space_estimate():
    light = light_at(10.0)
    albedo, k = per_point_truth(800, seed=14)
    noiseless = synthetic_observations(800, 12, light, albedo, k, np.random.default_rng(15))
    assert angle_between_deg(fit_varpro(noiseless, polish=False).light_dir_cam, light) < 1e-6
    noisy = synthetic_observations(800, 12, light, albedo, k, np.random.default_rng(15), noise_sigma=0.01)
    log_space = fit_varpro(noisy, polish=False)
    polished = fit_varpro(noisy)
    # The log-space fit is near but not at the least-squares optimum.
    assert log_space.cost > polished.cost
    assert angle_between_deg(log_space.light_dir_cam, polished.light_dir_cam) < 2 * polished.light_std_deg
    assert polished.stage_passes["polish"] >= 2


def test_noisy_fit_is_the_least_squares_optimum_of_the_joint_lm():
    light = light_at(10.0)
    albedo, k = per_point_truth(600, seed=16)
    obs = synthetic_observations(600, 12, light, albedo, k, np.random.default_rng(16), noise_sigma=0.01)
    result = fit_varpro(obs, sigma=0.01)
    joint = fit_koizumi_lm(obs)
    assert result.cost == pytest.approx(joint.cost, rel=1e-9)
    assert angle_between_deg(result.light_dir_cam, joint.light_dir_cam) < 1e-3 * result.light_std_deg
    assert np.max(np.abs(result.minnaert_k - joint.minnaert_k) / result.minnaert_k_std) < 1e-2
    # A per-observation sigma of the same value is the same fit.
    per_row = fit_varpro(obs, sigma=np.full(obs.n_obs, 0.01))
    assert angle_between_deg(per_row.light_dir_cam, result.light_dir_cam) < 1e-9
    assert np.allclose(per_row.minnaert_k_std, result.minnaert_k_std, rtol=1e-9)
    assert np.isnan(per_row.noise_sigma) and result.noise_sigma == 0.01


def test_light_search_escapes_the_local_minimum_of_the_iwano_start():
    # The case of test_estimate: Iwano's guess ~17 deg off, 6 views, noise.
    light = light_at(10.0)
    albedo, k = per_point_truth(600, seed=40)
    obs = synthetic_observations(600, 6, light, albedo, k, np.random.default_rng(40), noise_sigma=0.01)
    searched = fit_varpro(obs)
    from_truth = fit_koizumi_lm(obs, light_init=light)
    assert searched.cost == pytest.approx(from_truth.cost, rel=1e-9)
    assert angle_between_deg(searched.light_dir_cam, from_truth.light_dir_cam) < 1e-5


# --------------------------------------------------------------------------
# Robustness
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def contaminated():
    """1,500 points, 24 views, noise 0.003, and 2 % of the observations multiplied by 3."""
    light = light_at(10.0)
    albedo, k = per_point_truth(1500, seed=20)
    obs = synthetic_observations(1500, 24, light, albedo, k, np.random.default_rng(21), noise_sigma=0.003)
    rng = np.random.default_rng(22)
    outlier = rng.random(obs.n_obs) < 0.02
    brightness = np.where(outlier, 3.0 * obs.brightness, obs.brightness)
    bad = Observations(obs.point_index, obs.normal_cam, obs.view_cam, brightness, obs.n_points)
    clean_fit = fit_varpro(obs, sigma=0.003)
    return bad, outlier, light, albedo, k, clean_fit


def errors(result, light, albedo, k):
    return (
        angle_between_deg(result.light_dir_cam, light),
        float(np.sqrt(np.nanmean((result.albedo - albedo) ** 2))),
        float(np.sqrt(np.nanmean((result.minnaert_k - k) ** 2))),
    )


def test_plain_least_squares_is_biased_by_outliers(contaminated):
    bad, _, light, albedo, k, clean_fit = contaminated
    plain = fit_varpro(bad)
    light_error, albedo_rmse, _ = errors(plain, light, albedo, k)
    assert light_error > 10 * clean_fit.light_std_deg
    assert albedo_rmse > 5 * errors(clean_fit, light, albedo, k)[1]


@pytest.mark.parametrize(
    "options",
    [dict(loss="huber", reject_outliers=True), dict(loss="cauchy"), dict(loss="cauchy", reject_outliers=True), dict(reject_outliers=True, sigma=0.003)],
    ids=["huber+reject", "cauchy", "cauchy+reject", "linear+reject"],
)
def test_robust_fits_ignore_the_outliers(contaminated, options):
    bad, outlier, light, albedo, k, clean_fit = contaminated
    result = fit_varpro(bad, **options)
    assert result.success, result.message
    light_error, albedo_rmse, k_rmse = errors(result, light, albedo, k)
    _, clean_albedo_rmse, clean_k_rmse = errors(clean_fit, light, albedo, k)
    assert light_error < 3 * clean_fit.light_std_deg
    assert albedo_rmse < 1.3 * clean_albedo_rmse
    assert k_rmse < 1.3 * clean_k_rmse
    if options.get("reject_outliers"):
        used = result.observation_used
        assert not np.any(used & outlier)  # every outlier rejected ...
        assert np.count_nonzero(~used & ~outlier) < 0.002 * bad.n_obs  # ... and few good rows
        assert result.n_rejected == np.count_nonzero(~used)


# --------------------------------------------------------------------------
# Uncertainty
# --------------------------------------------------------------------------


@pytest.mark.parametrize("sigma_known", [True, False])
def test_uncertainties_match_the_observed_scatter(sigma_known):
    light = light_at(10.0)
    albedo, k = per_point_truth(3000, seed=30)
    obs = synthetic_observations(3000, 16, light, albedo, k, np.random.default_rng(31), noise_sigma=0.01)
    result = fit_varpro(obs, sigma=0.01 if sigma_known else None)
    assert result.sigma_estimated is not sigma_known
    assert result.noise_sigma == pytest.approx(0.01, rel=0.02)
    assert result.reduced_chi2 == pytest.approx(1.0, abs=0.03) if sigma_known else True
    # Squared errors in units of the predicted variance average to 1 (3000 points: +-0.03).
    assert np.mean(((result.albedo - albedo) / result.albedo_std) ** 2) == pytest.approx(1.0, abs=0.1)
    assert np.mean(((result.minnaert_k - k) / result.minnaert_k_std) ** 2) == pytest.approx(1.0, abs=0.1)
    # The predicted correlation of albedo and k shows in the errors.
    predicted = np.mean(result.albedo_k_cov / (result.albedo_std * result.minnaert_k_std))
    observed = np.corrcoef(result.albedo - albedo, result.minnaert_k - k)[0, 1]
    assert observed == pytest.approx(predicted, abs=0.05)
    assert angle_between_deg(result.light_dir_cam, light) < 3 * result.light_std_deg


def test_light_covariance_matches_repeated_fits():
    light = light_at(10.0)
    albedo, k = per_point_truth(150, seed=32)
    errors_tangent, covariances = [], []
    for seed in range(40):
        obs = synthetic_observations(150, 12, light, albedo, k, np.random.default_rng(1000 + seed), noise_sigma=0.01)
        result = fit_varpro(obs, sigma=0.01)
        errors_tangent.append(result.light_tangent - tangent_from_light(light))
        covariances.append(result.light_cov_tangent)
    errors_tangent = np.array(errors_tangent)
    mean_cov = np.mean(covariances, axis=0)
    # Mahalanobis^2 averages 2 (chi-square, 2 dof); 40 fits: +-0.45.
    mahalanobis2 = np.einsum("ni,ij,nj->n", errors_tangent, np.linalg.inv(mean_cov), errors_tangent)
    assert np.mean(mahalanobis2) == pytest.approx(2.0, abs=0.8)


# --------------------------------------------------------------------------
# Validation and bookkeeping
# --------------------------------------------------------------------------


def test_fit_varpro_rejects_unusable_input():
    obs = synthetic_observations(30, 6, light_at(0.0), 0.5, 0.8, np.random.default_rng(0))
    empty = Observations(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 4)
    with pytest.raises(ValueError, match="cannot determine"):
        fit_varpro(empty)
    with pytest.raises(ValueError, match="loss must be one of"):
        fit_varpro(obs, loss="soft_l1")
    with pytest.raises(ValueError, match="sigma must be a positive"):
        fit_varpro(obs, sigma=0.0)
    with pytest.raises(ValueError, match="sigma must be a scalar or have shape"):
        fit_varpro(obs, sigma=np.ones(3))
    with pytest.raises(ValueError, match="every sigma must be finite"):
        fit_varpro(obs, sigma=np.full(obs.n_obs, -1.0))
    with pytest.raises(ValueError, match="f_scale must be > 0"):
        fit_varpro(obs, loss="huber", f_scale=0.0)
    with pytest.raises(ValueError, match="light_init must be"):
        fit_varpro(obs, light_init="lambert")
    with pytest.raises(ValueError, match="l_z < 0"):
        fit_varpro(obs, light_init=[0.0, 0.0, 1.0])


def test_streaming_chunks_do_not_change_the_answer():
    light = light_at(10.0)
    albedo, k = per_point_truth(500, seed=50)
    obs = synthetic_observations(500, 12, light, albedo, k, np.random.default_rng(50), noise_sigma=0.01)
    small = fit_varpro(obs, chunk_rows=100)
    large = fit_varpro(obs, chunk_rows=1 << 20)
    assert angle_between_deg(small.light_dir_cam, large.light_dir_cam) < 1e-10
    assert np.allclose(small.minnaert_k, large.minnaert_k, rtol=0, atol=1e-10)
    assert np.allclose(small.albedo_std, large.albedo_std, rtol=1e-9)


def test_module_exports_exist():
    for name in varpro.__all__:
        assert hasattr(varpro, name)
