"""The light step under a sensor: a k per point held to the body's, a gain per image (estimation.hierarchical),
and the normals' common turn (refine.common_turn_deg)."""

import numpy as np
import pytest

from asteroid_photometry.estimation import angle_between_deg, fit_pooled_k, light_from_tangent, Observations
from asteroid_photometry.estimation.hierarchical import fit_light_k_prior
from asteroid_photometry.from_images.refine import common_turn_deg


def turning_body(rng, n_points=400, n_images=36, k_mean=0.9, k_sd=0.1, gain_sigma=0.02, noise=0.005, light=(0.12, 0.05)):
    """Points of a body turning about the camera's y axis, seen in every image where lit and visible: their
    observations, the image of each row, and the truth (light, per-point k, per-image gains)."""
    light_dir = light_from_tangent(np.asarray(light))
    normals = rng.normal(size=(n_points, 3))
    normals[:, 1] *= 0.6  # keep away from the poles, so every point turns through an arc
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    albedo = rng.uniform(0.4, 0.6, n_points)
    k = k_mean + k_sd * rng.standard_normal(n_points)
    gains = np.exp(gain_sigma * rng.standard_normal(n_images))
    point_index, image_index, normal_cam, brightness = [], [], [], []
    for image, phase in enumerate(np.linspace(0.0, 2 * np.pi, n_images, endpoint=False)):
        c, s = np.cos(phase), np.sin(phase)
        turned = normals @ np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]).T
        cos_i, cos_o = turned @ light_dir, -turned[:, 2]
        seen = (cos_i > 0.1) & (cos_o > 0.1)
        b = gains[image] * albedo * np.clip(cos_i, 0.1, None) ** k * np.clip(cos_o, 0.1, None) ** (k - 1.0)
        b = b * (1.0 + noise * rng.standard_normal(n_points))
        point_index.append(np.flatnonzero(seen))
        image_index.append(np.full(seen.sum(), image))
        normal_cam.append(turned[seen])
        brightness.append(b[seen])
    normal_cam = np.concatenate(normal_cam)
    view = np.tile([0.0, 0.0, -1.0], (len(normal_cam), 1))
    obs = Observations(np.concatenate(point_index), normal_cam, view, np.concatenate(brightness), n_points)
    return obs, np.concatenate(image_index), dict(light=light_dir, k=k, gains=gains)


def test_light_gains_and_k_are_recovered_where_one_k_is_not():
    rng = np.random.default_rng(3)
    obs, image_index, truth = turning_body(rng)
    start = light_from_tangent(np.array([0.15, 0.08]))
    fit = fit_light_k_prior(obs, image_index, start, 0.9, relative_sd=0.005, k_prior_sd=0.1, gain_sigma=0.02, n_images=36)
    error = angle_between_deg(fit.light_dir_cam, truth["light"])
    pooled = angle_between_deg(fit_pooled_k(obs, start, 0.9).light_dir_cam, truth["light"])
    assert error < 0.2
    assert pooled > 3 * error  # one k for a body whose k varies by 0.1, and the gains left in
    log_gain_error = np.log(fit.gains) - np.log(truth["gains"])
    assert np.std(log_gain_error) < 0.004  # the 2 % gains to better than 0.4 %, up to their common factor
    assert abs(np.sum(np.log(fit.gains))) < 1e-6  # the gauge: geometric mean 1
    fitted = np.isfinite(fit.minnaert_k)
    assert np.corrcoef(fit.minnaert_k[fitted], truth["k"][fitted])[0, 1] > 0.8
    assert abs(fit.body_k - np.mean(truth["k"])) < 0.02


def test_without_gain_prior_no_gain_is_fitted():
    rng = np.random.default_rng(4)
    obs, image_index, truth = turning_body(rng, gain_sigma=0.0)
    fit = fit_light_k_prior(obs, image_index, truth["light"], 0.9, relative_sd=0.005, k_prior_sd=0.1, n_images=36)
    assert np.all(fit.gains == 1.0)
    assert angle_between_deg(fit.light_dir_cam, truth["light"]) < 0.2


def test_bad_arguments_are_refused():
    rng = np.random.default_rng(5)
    obs, image_index, truth = turning_body(rng, n_points=30)
    with pytest.raises(ValueError, match="image_index"):
        fit_light_k_prior(obs, image_index[:-1], truth["light"], 0.9, relative_sd=0.005, k_prior_sd=0.1)
    with pytest.raises(ValueError, match="k_prior_sd"):
        fit_light_k_prior(obs, image_index, truth["light"], 0.9, relative_sd=0.005, k_prior_sd=0.0)


def test_common_turn_of_the_normals_is_measured_about_the_axis():
    rng = np.random.default_rng(6)
    axis = np.array([0.0, 1.0, 0.0])
    surface = rng.normal(size=(2000, 3))
    surface /= np.linalg.norm(surface, axis=1, keepdims=True)
    angle = np.radians(3.0 + rng.normal(0.0, 4.0, len(surface)))  # a common 3 deg and a scatter of 4 about it
    c, s = np.cos(angle), np.sin(angle)
    fitted = np.column_stack([c * surface[:, 0] + s * surface[:, 2], surface[:, 1], -s * surface[:, 0] + c * surface[:, 2]])
    turn = common_turn_deg(fitted, surface, axis)
    assert abs(abs(turn) - 3.0) < 0.4
    assert common_turn_deg(fitted, surface, -axis) == pytest.approx(-turn)
    assert common_turn_deg(surface, surface, axis) == pytest.approx(0.0, abs=1e-9)
