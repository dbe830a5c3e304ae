"""The geometry sensitivity study: random normal tilts of a known size, applied consistently to every view of a point."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from asteroid_photometry import estimation
from asteroid_photometry.experiments import sensitivity


def _unit(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("median_deg", [0.5, 4.0, 10.0])
def test_tilts_have_the_asked_median_and_no_preferred_direction(median_deg):
    rng = np.random.default_rng(1)
    normals = _unit(rng, 20000)
    tilted, angles = sensitivity.tilt_normals(normals, median_deg, np.random.default_rng(2))
    np.testing.assert_allclose(np.linalg.norm(tilted, axis=1), 1.0, atol=1e-12)
    measured = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", tilted, normals), -1, 1)))
    np.testing.assert_allclose(measured, angles, atol=1e-6)
    assert abs(np.median(angles) / median_deg - 1) < 0.03
    # Tilts towards random directions: their mean change is much smaller than a typical one.
    assert np.linalg.norm((tilted - normals).mean(axis=0)) < 0.05 * np.deg2rad(median_deg)


def test_zero_tilt_keeps_the_normals():
    normals = _unit(np.random.default_rng(3), 100)
    tilted, angles = sensitivity.tilt_normals(normals, 0.0, np.random.default_rng(4))
    np.testing.assert_allclose(tilted, normals, atol=1e-15)
    assert (angles == 0).all()


def test_a_point_is_tilted_the_same_way_in_every_view():
    rng = np.random.default_rng(5)
    n_points, n_images = 50, 6
    rotations = Rotation.random(n_images, random_state=6).as_matrix()
    normals = _unit(rng, n_points)
    point_index = np.repeat(np.arange(n_points), n_images)
    image_index = np.tile(np.arange(n_images), n_points)
    normal_cam = np.einsum("nij,nj->ni", rotations[image_index], normals[point_index])
    arrays = {
        "point_index": point_index, "image_index": image_index, "normal_cam": normal_cam,
        "view_cam": normal_cam.copy(),  # every view along the normal: nothing is dropped at small tilts
        "brightness": np.ones(len(point_index)), "n_points": n_points,
    }
    obs, median = sensitivity.tilted_observations(arrays, rotations, 3.0, np.random.default_rng(7), min_cos_emission=0.1)
    assert isinstance(obs, estimation.Observations) and obs.n_obs == len(point_index)
    body = np.einsum("nji,nj->ni", rotations[image_index], obs.normal_cam)
    per_point = body.reshape(n_points, n_images, 3)
    np.testing.assert_allclose(per_point, per_point[:, :1, :].repeat(n_images, axis=1), atol=1e-12)  # one tilted normal per point
    angles = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", per_point[:, 0], normals), -1, 1)))
    assert angles.max() > 1.0 and abs(np.median(angles) - median) < 1e-9
    # Zero tilt gives the observations back unchanged.
    same, _ = sensitivity.tilted_observations(arrays, rotations, 0.0, np.random.default_rng(7), min_cos_emission=0.1)
    np.testing.assert_allclose(same.normal_cam, normal_cam, atol=1e-12)


def test_summary_counts_the_sets_within_the_bounds():
    import pandas as pd

    rows = []
    for set_id, light in (("a", 0.1), ("b", 0.9)):
        rows.append({"set_id": set_id, "variant": "pure_pixels", "normal_error_deg": 2.0, "normal_error_deg_median": 2.0,
                     "light_dir_err_deg": light, "albedo_err": 0.001, "k_err": -0.002, "albedo_rmse": 0.0, "k_rmse": 0.0, "n_points": 10, "n_obs": 50})
    text = sensitivity.sensitivity_markdown(pd.DataFrame(rows))
    assert "| pure_pixels | 2.00 | 0.500 / 0.900 |" in text
    assert "| 1 / 2 |" in text


def test_points_of_implausible_k_are_left_out_of_the_score():
    from asteroid_photometry.experiments.table2 import plausible_points

    result = estimation.FitResult(
        method="koizumi_lm", light_dir_cam=np.array([0.0, 0.0, 1.0]), albedo=np.array([0.5, 1e6, np.nan, 0.6]),
        minnaert_k=np.array([0.8, 4.5, np.nan, 1.1]), n_points_fitted=3, n_obs=40, cost=0.0, n_iterations=1, nfev=1,
        success=True, message="", fit_seconds=0.0,
    )
    kept = plausible_points(result)
    assert kept.n_points_fitted == 2
    np.testing.assert_array_equal(np.isfinite(kept.albedo), [True, False, False, True])
    np.testing.assert_array_equal(np.isfinite(kept.minnaert_k), [True, False, False, True])
    assert plausible_points(kept) is kept  # nothing left to drop


def test_latitude_and_longitude_tilts_move_the_normal_along_its_meridian_or_its_parallel():
    normals = _unit(np.random.default_rng(8), 2000)
    normals = normals[np.abs(normals[:, 2]) < 0.95]  # away from the poles, where longitude is ill-defined
    longitude = np.arctan2(normals[:, 1], normals[:, 0])
    latitude = np.arcsin(normals[:, 2])
    along_meridian, angles = sensitivity.tilt_normals(normals, 3.0, np.random.default_rng(9), "latitude")
    np.testing.assert_allclose(np.arctan2(along_meridian[:, 1], along_meridian[:, 0]), longitude, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.arcsin(along_meridian[:, 2]) - latitude), np.deg2rad(angles), atol=1e-9)
    along_parallel, angles = sensitivity.tilt_normals(normals, 3.0, np.random.default_rng(9), "longitude")
    # A great-circle step along the parallel's tangent: no first-order change of latitude, sin(lat) * cos(tilt) exactly.
    np.testing.assert_allclose(along_parallel[:, 2], normals[:, 2] * np.cos(np.deg2rad(angles)), atol=1e-12)
    assert np.abs(np.angle(np.exp(1j * (np.arctan2(along_parallel[:, 1], along_parallel[:, 0]) - longitude)))).max() > np.deg2rad(1.0)
    with pytest.raises(ValueError, match="tilt direction"):
        sensitivity.tilt_normals(normals, 3.0, np.random.default_rng(9), "sideways")
