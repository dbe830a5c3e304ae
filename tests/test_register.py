"""Tests of asteroid_photometry.from_images.register (registration onto the shape model) and .quality (scores).

The registration tests use Ostro's radar model of Itokawa, shipped with the
workflow: known similarity transforms, a hole of 30 %, the
end-over-end ambiguity, and clouds that are not the body. Surface distances
and the quality scores are also checked on a box with exact answers.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from asteroid_photometry.core.failures import DataFailure
from asteroid_photometry.evaluation.quality import completeness, point_scores, reconstruction_quality
from asteroid_photometry.from_images import register
from asteroid_photometry.from_images.register import register_to_shape
from asteroid_photometry.world import mesh
from asteroid_photometry.world.mesh import (
    closest_facet,
    decompose_similarity,
    point_to_surface_distance,
    rotation_angle_deg,
    sample_surface,
    similarity_transform,
    transform_normals,
    transform_points,
)
from asteroid_photometry.world.shape import facet_geometry, load_shape_model
from synthetic_helpers import BOX_CORNERS, BOX_FACES

# A box 200 x 100 x 50 m centred on the origin, facets counter-clockwise seen from outside.
BOX_HALF_M = np.array([100.0, 50.0, 25.0])
BOX_VERTICES_M = BOX_HALF_M * BOX_CORNERS


@pytest.fixture(scope="module")
def ostro(itokawa_dir):
    model = load_shape_model(itokawa_dir / "25143itokawa.tab", "ostro_radar")
    return model.vertices_m, model.faces


def surface_cloud(vertices_m, faces, n_points, rng, noise_rel=0.0, hole_fraction=0.0):
    """Points on the surface with their facets' normals, optional Gaussian noise and a hole.

    The hole is the ``hole_fraction`` of the points nearest to a random one.
    """
    length_m = register.body_length_m(vertices_m, faces)
    n_drawn = int(round(n_points / (1.0 - hole_fraction)))
    points, facet_ids = sample_surface(vertices_m, faces, n_drawn, rng)
    normals = facet_geometry(vertices_m, faces)[1][facet_ids]
    if hole_fraction > 0:
        distance = np.linalg.norm(points - points[rng.integers(len(points))], axis=1)
        kept = distance > np.quantile(distance, hole_fraction)
        points, normals = points[kept], normals[kept]
    points = points + rng.normal(scale=noise_rel * length_m, size=points.shape)
    return points, normals, length_m


def random_similarity(rng, scale, length_m):
    """A body-to-input similarity: random rotation, the given scale, a translation of about one length."""
    rotation = Rotation.random(random_state=rng).as_matrix()
    translation = rng.normal(size=3) / np.sqrt(3) * length_m * scale
    return similarity_transform(scale, rotation, translation)


def assert_recovers(result, body_to_input, length_m):
    """The registration undoes ``body_to_input``: rotation 1 deg, scale 1 %, translation 1 % of the length."""
    scale_true, rotation_true, translation_true = decompose_similarity(np.linalg.inv(body_to_input))
    assert rotation_angle_deg(result.rotation, rotation_true) < 1.0
    assert result.scale == pytest.approx(scale_true, rel=0.01)
    assert np.linalg.norm(result.translation_m - translation_true) < 0.01 * length_m
    # Where the body's origin lands: independent of where the input frame's origin is.
    assert np.linalg.norm(result.apply(body_to_input[:3, 3][None])) < 0.01 * length_m


# ---------------------------------------------------------------- transforms and surface distances


def test_similarity_round_trip():
    rotation = Rotation.from_euler("xyz", [30, -50, 120], degrees=True).as_matrix()
    transform = similarity_transform(0.02, rotation, [1.0, -2.0, 3.0])
    scale, rotation_back, translation = decompose_similarity(transform)
    assert scale == pytest.approx(0.02)
    assert np.allclose(rotation_back, rotation)
    assert np.allclose(translation, [1.0, -2.0, 3.0])
    points = np.array([[1.0, 0.0, 0.0], [0.0, 5.0, -1.0]])
    assert np.allclose(transform_points(transform, points), 0.02 * points @ rotation.T + [1.0, -2.0, 3.0])
    assert np.allclose(transform_normals(transform, points[:1]), points[:1] @ rotation.T)
    assert rotation_angle_deg(rotation, rotation) == pytest.approx(0.0, abs=1e-5)
    turned = Rotation.from_rotvec([0, 0, np.radians(40)]).as_matrix() @ rotation
    assert rotation_angle_deg(turned, rotation) == pytest.approx(40.0)
    with pytest.raises(ValueError, match="reflection"):
        decompose_similarity(np.diag([1.0, 1.0, -1.0, 1.0]))


def test_distance_and_closest_facet_on_a_box():
    points = np.array([[0.0, 0.0, 35.0], [0.0, 0.0, 0.0], [110.0, 0.0, 0.0], [103.0, 54.0, 0.0], [-50.0, 0.0, -25.0]])
    expected = [10.0, 25.0, 10.0, 5.0, 0.0]
    assert np.allclose(point_to_surface_distance(points, BOX_VERTICES_M, BOX_FACES), expected, atol=1e-4)
    facet_ids = closest_facet(points[[0, 2]], BOX_VERTICES_M, BOX_FACES)
    assert set(facet_ids[:1]) <= {2, 3}  # the +z facets
    assert set(facet_ids[1:]) <= {10, 11}  # the +x facets


def test_sample_surface_is_area_weighted_and_on_the_surface():
    points, facet_ids = sample_surface(BOX_VERTICES_M, BOX_FACES, 60_000, seed=1)
    assert np.allclose(point_to_surface_distance(points, BOX_VERTICES_M, BOX_FACES), 0.0, atol=1e-4)
    _, _, areas = facet_geometry(BOX_VERTICES_M, BOX_FACES)
    share = np.bincount(facet_ids, minlength=len(BOX_FACES)) / len(facet_ids)
    assert np.allclose(share, areas / areas.sum(), atol=0.005)


def test_body_length_is_the_long_axis():
    assert register.body_length_m(BOX_VERTICES_M, BOX_FACES) == pytest.approx(200.0)
    rotation = Rotation.from_euler("zyx", [20, 30, 40], degrees=True).as_matrix()
    assert register.body_length_m(BOX_VERTICES_M @ rotation.T, BOX_FACES) == pytest.approx(200.0)


def test_ostro_length(ostro):
    # SOURCES.md: bounding box 548.1 x 312.6 x 275.5 m in the principal-axis frame.
    assert register.body_length_m(*ostro) == pytest.approx(548.1, abs=1.0)


# ---------------------------------------------------------------- registration


@pytest.mark.parametrize(
    "seed, scale, with_normals",
    [(1, 0.01, True), (2, 100.0, False), (3, None, True)],
    ids=["scale0.01-normals", "scale100-no-normals", "random-scale"],
)
def test_recovers_a_random_similarity_despite_a_hole(ostro, seed, scale, with_normals):
    rng = np.random.default_rng(seed)
    points, normals, length_m = surface_cloud(*ostro, 5000, rng, noise_rel=0.002, hole_fraction=0.3)
    scale = scale if scale is not None else 10 ** rng.uniform(-2, 2)
    body_to_input = random_similarity(rng, scale, length_m)
    result = register_to_shape(
        transform_points(body_to_input, points),
        transform_normals(body_to_input, normals) if with_normals else None,
        *ostro,
        seed=seed,
    )
    assert result.success, result.summary()
    assert_recovers(result, body_to_input, length_m)
    assert result.fitness > 0.98
    assert result.rms_distance_rel < 0.004  # the 0.2 % noise, and little more
    assert result.seconds_global > 0 and result.seconds_icp > 0


def test_recovers_the_end_over_end_turn(ostro):
    """Itokawa turned 180 degrees about its long axis: the pose a rigid search most easily confuses."""
    vertices_m, faces = ostro
    rng = np.random.default_rng(4)
    points, normals, length_m = surface_cloud(vertices_m, faces, 5000, rng, noise_rel=0.002)
    centroid, axes = mesh.principal_axes(vertices_m, faces)
    turn = Rotation.from_rotvec(np.pi * axes[:, 0]).as_matrix()
    body_to_input = similarity_transform(1.0, turn, centroid - turn @ centroid)
    result = register_to_shape(
        transform_points(body_to_input, points), transform_normals(body_to_input, normals), vertices_m, faces
    )
    assert result.success, result.summary()
    assert_recovers(result, body_to_input, length_m)
    assert result.ambiguity < 0.5


def test_metric_cloud_near_the_body_frame_keeps_scale_one(ostro):
    """With position priors: scale known, a rough pose given, ICP alone from it."""
    vertices_m, faces = ostro
    rng = np.random.default_rng(5)
    points, normals, length_m = surface_cloud(vertices_m, faces, 4000, rng, noise_rel=0.002)
    small_turn = Rotation.from_rotvec(np.radians(4.0) * np.array([0.6, 0.0, 0.8])).as_matrix()
    body_to_input = similarity_transform(1.0, small_turn, [8.0, -5.0, 3.0])
    result = register_to_shape(
        transform_points(body_to_input, points),
        None,
        vertices_m,
        faces,
        estimate_scale=False,
        init_transform=np.eye(4),
        global_search=False,
    )
    assert result.scale == pytest.approx(1.0, abs=1e-9)
    assert result.success and np.isnan(result.ambiguity)
    assert_recovers(result, body_to_input, length_m)


def sphere_points(n_points, rng, radius):
    directions = rng.normal(size=(n_points, 3))
    return radius * directions / np.linalg.norm(directions, axis=1, keepdims=True)


@pytest.mark.parametrize("shape", ["sphere", "blob"])
def test_a_cloud_that_is_not_the_body_fails(ostro, shape):
    rng = np.random.default_rng(6)
    if shape == "sphere":
        points = sphere_points(2000, rng, 37.0) + [5.0, -3.0, 2.0]
    else:
        points = rng.normal(size=(2000, 3)) * [3.0, 2.0, 1.0]  # a Gaussian blob, no surface at all
    result = register_to_shape(points, None, *ostro, seed=0)
    assert not result.success
    assert result.failure_reason.startswith("registration failed: ")
    if shape == "sphere":
        assert result.fitness < 0.9
        assert "fitness" in result.failure_reason


def test_an_ellipsoid_of_the_body_size_fails_as_ambiguous(ostro):
    """Fits Itokawa's surface to 1 % of its length, but every end-over-end pose fits as well."""
    rng = np.random.default_rng(7)
    points = sphere_points(4000, rng, 1.0) * [274.0, 156.0, 138.0]
    result = register_to_shape(points, None, *ostro, seed=0)
    assert not result.success
    assert result.ambiguity > 0.5
    assert "no unambiguous pose" in result.failure_reason


def test_rejects_malformed_input(ostro):
    with pytest.raises(ValueError, match="shape"):
        register_to_shape(np.zeros((10, 2)), None, *ostro)
    with pytest.raises(DataFailure, match="at least 30"):
        register_to_shape(np.full((100, 3), np.nan), None, *ostro)
    with pytest.raises(ValueError, match="normals"):
        register_to_shape(np.zeros((100, 3)), np.zeros((99, 3)), *ostro)
    with pytest.raises(ValueError, match="init_transform"):
        register_to_shape(np.random.default_rng(0).normal(size=(100, 3)), None, *ostro, global_search=False)


# ---------------------------------------------------------------- quality


def test_points_on_the_surface_score_perfectly(ostro):
    vertices_m, faces = ostro
    points, facet_ids = sample_surface(vertices_m, faces, 20_000, seed=8)
    normals = facet_geometry(vertices_m, faces)[1][facet_ids]
    quality = reconstruction_quality(points, normals, vertices_m, faces, n_surface_samples=20_000)
    assert quality.accuracy_median_m < 1e-3 and quality.accuracy_p90_m < 1e-3
    assert quality.accuracy_median_rel < 1e-5
    assert quality.normal_error_median_deg < 1e-3
    assert quality.flipped_normal_fraction == 0.0
    # Uniform random points leave random gaps: a surface sample is missed when
    # no point falls within the threshold r of it, with probability exp(-n pi r^2 / area).
    threshold_m = quality.completeness_threshold_m
    assert threshold_m == pytest.approx(0.01 * quality.body_length_m)
    area_m2 = facet_geometry(vertices_m, faces)[2].sum()
    expected = 1.0 - np.exp(-len(points) * np.pi * threshold_m**2 / area_m2)
    assert quality.completeness == pytest.approx(expected, abs=0.003)
    # The closest facet is the one the point was drawn on (up to points on shared edges).
    assert np.mean(point_scores(points, None, vertices_m, faces).facet_id == facet_ids) > 0.99


def test_offset_points_and_flipped_normals(ostro):
    vertices_m, faces = ostro
    centroids_m, normals, _ = facet_geometry(vertices_m, faces)
    offset_m = 0.5
    quality = reconstruction_quality(
        centroids_m + offset_m * normals, -normals, vertices_m, faces, n_surface_samples=20_000
    )
    assert quality.accuracy_median_m == pytest.approx(offset_m, rel=0.05)
    assert quality.normal_error_median_deg == pytest.approx(180.0, abs=0.1)
    assert quality.normal_error_median_unsigned_deg == pytest.approx(0.0, abs=0.1)
    assert quality.flipped_normal_fraction > 0.99


def test_half_covered_surface_is_half_complete(ostro):
    vertices_m, faces = ostro
    samples, _ = sample_surface(vertices_m, faces, 120_000, seed=9)
    long_axis_coordinate = samples[:, 0]
    half = samples[long_axis_coordinate < np.median(long_axis_coordinate)]
    threshold_m = 5.0
    assert completeness(half, vertices_m, faces, threshold_m, n_samples=40_000, seed=10) == pytest.approx(0.5, abs=0.02)
    assert completeness(samples, vertices_m, faces, threshold_m, n_samples=40_000, seed=10) > 0.999


def test_quality_in_the_input_frame_with_the_transform(ostro):
    vertices_m, faces = ostro
    points, facet_ids = sample_surface(vertices_m, faces, 5000, seed=11)
    normals = facet_geometry(vertices_m, faces)[1][facet_ids]
    body_to_input = random_similarity(np.random.default_rng(12), 0.03, 550.0)
    in_body = reconstruction_quality(points, normals, vertices_m, faces, n_surface_samples=10_000)
    from_input = reconstruction_quality(
        transform_points(body_to_input, points),
        transform_normals(body_to_input, normals),
        vertices_m,
        faces,
        transform=np.linalg.inv(body_to_input),
        n_surface_samples=10_000,
    )
    assert from_input.accuracy_p90_m == pytest.approx(in_body.accuracy_p90_m, abs=1e-3)
    assert from_input.completeness == pytest.approx(in_body.completeness, abs=1e-3)
    assert from_input.normal_error_median_deg == pytest.approx(in_body.normal_error_median_deg, abs=0.01)
    summary = from_input.summary()
    assert summary["n_points"] == 5000 and isinstance(summary["completeness"], float)
