"""The oriented cloud of Table 2: outliers, normals, visibility and sampling, on a ball with known answers."""

import numpy as np
import pytest

from asteroid_photometry.from_images import cloud
from asteroid_photometry.world.cameras import Intrinsics

pytest.importorskip("open3d")

RADIUS = 100.0


def _ball(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return RADIUS * directions, directions


def _camera_on(axis, distance=5 * RADIUS):
    """A body-to-camera pose (OpenCV: z forward) looking at the centre from ``distance`` along ``axis``."""
    centre = distance * np.asarray(axis, dtype=float)
    forward = -centre / np.linalg.norm(centre)
    helper = np.array([1.0, 0, 0]) if abs(forward[0]) < 0.9 else np.array([0, 1.0, 0])
    right = np.cross(forward, helper)
    right /= np.linalg.norm(right)
    rotation = np.stack([right, np.cross(forward, right), forward])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, -rotation @ centre
    return pose, centre


def test_oriented_cloud_drops_outliers_and_turns_normals_to_the_cameras():
    points, directions = _ball()
    far = np.array([[10 * RADIUS, 0, 0], [0, -9 * RADIUS, 3 * RADIUS]])
    points = np.vstack([points, far])
    # Six cameras on the axes; every point is in the track of the three that see it best.
    axes = np.vstack([np.eye(3), -np.eye(3)])
    centres = {i: _camera_on(axis)[1] for i, axis in enumerate(axes)}
    unit = points / np.linalg.norm(points, axis=1, keepdims=True)
    track_point = np.repeat(np.arange(len(points)), 3)
    track_image = np.argsort(-(unit @ axes.T), axis=1)[:, :3].ravel()
    result = cloud.oriented_cloud(points, track_point, track_image, centres, min_track=3)
    assert len(result.points) >= 0.95 * len(directions)
    assert not np.any(np.linalg.norm(result.points, axis=1) > 2 * RADIUS), "the far outliers stay"
    outward = result.points / RADIUS
    cos = np.einsum("ij,ij->i", result.normals, outward)
    assert np.median(cos) > 0.99 and np.mean(cos > 0) > 0.99


def test_poisson_surface_is_reproducible_and_on_the_ball():
    points, directions = _ball()
    oriented = cloud.OrientedCloud(points, directions, np.full(len(points), 3))
    vertices, triangles = cloud.poisson_surface(oriented)
    again, _ = cloud.poisson_surface(oriented)
    assert np.array_equal(vertices, again)
    assert len(triangles) > 1000
    assert np.abs(np.median(np.linalg.norm(vertices, axis=1)) / RADIUS - 1) < 0.02


def test_visibility_is_the_near_cap_facing_the_camera():
    points, directions = _ball()
    oriented = cloud.OrientedCloud(points, directions, np.full(len(points), 3))
    pose, centre = _camera_on([0, 0, 1])
    point_ids, image_ids = cloud.visible_pairs(oriented, {7: pose}, min_cos_emission=0.2, occlusion_tolerance=0.02 * RADIUS)
    assert set(image_ids) == {7}
    to_camera = centre - points
    cos_emission = np.einsum("ij,ij->i", directions, to_camera) / np.linalg.norm(to_camera, axis=1)
    expected = np.flatnonzero(cos_emission >= 0.2)
    assert set(point_ids) == set(expected)
    # A point hidden behind the ball is not seen even when its normal faces the camera.
    hidden = cloud.OrientedCloud(np.vstack([points, [0, 0, -0.5 * RADIUS]]), np.vstack([directions, [0, 0, 1]]), np.full(len(points) + 1, 3))
    point_ids, _ = cloud.visible_pairs(hidden, {7: pose}, min_cos_emission=0.2, occlusion_tolerance=0.02 * RADIUS)
    assert len(points) not in set(point_ids)


def test_sample_bilinear_reads_pixel_centres_and_interpolates():
    image = np.add.outer(np.arange(6.0), 10 * np.arange(8.0))  # value = row + 10 * column
    uv = np.array([[0.5, 0.5], [3.5, 2.5], [4.0, 2.5], [3.5, 3.0]])  # (u = x, v = y); pixel centres at +0.5
    assert np.allclose(cloud.sample_bilinear(image, uv), [0.0, 32.0, 37.0, 32.5])


def test_cloud_observations_sample_each_point_where_it_projects():
    points, directions = _ball(n=2000)
    oriented = cloud.OrientedCloud(points, directions, np.full(len(points), 3))
    intrinsics = Intrinsics(width=256, height=256, focal_px=600.0, cx=128.0, cy=128.0)
    pose, _ = _camera_on([0, 0, 1])
    # An image whose value encodes the pixel position: each sample says where it was taken.
    rows, columns = np.mgrid[0:256, 0:256]
    image = 1.0 + columns + 1000.0 * rows
    obs, image_index = cloud.cloud_observations(oriented, {0: pose}, intrinsics, [image], min_cos_emission=0.3, min_observations=1)
    assert obs.n_obs > 200 and set(image_index) == {0}
    points_cam = points[obs.point_index] @ pose[:3, :3].T + pose[:3, 3]
    uv = points_cam[:, :2] / points_cam[:, 2:] * intrinsics.focal_px + [intrinsics.cx, intrinsics.cy]
    assert np.allclose(obs.brightness, 1.0 + (uv[:, 0] - 0.5) + 1000.0 * (uv[:, 1] - 0.5), atol=1e-6)
    assert np.all(obs.cos_emission >= 0.3)


def test_pure_samples_are_those_whose_bilinear_pixels_agree():
    # Two flat regions split by a vertical edge between pixel columns 9 and 10,
    # and one mixed column (10) that averages them, as a facet edge renders.
    image = np.full((20, 20), 0.30)
    image[:, 10] = 0.42
    image[:, 11:] = 0.60
    # Pixel centres sit at half-integer (u, v); a sample reads the four around it.
    uv = np.array([[5.0, 5.0], [15.0, 8.0], [10.0, 5.0], [10.6, 12.0], [11.2, 3.0]])
    values = cloud.sample_pure(image, uv, tolerance=1e-3)
    np.testing.assert_allclose(values[:2], [0.30, 0.60])
    assert (values[2:] == 0).all()  # every sample that reads the mixed column or straddles the edge
    # A tolerance wider than the step between regions lets mixtures through.
    assert cloud.sample_pure(image, uv[2:3], tolerance=0.5)[0] > 0
    # Unlit pixels are never pure samples.
    assert cloud.sample_pure(np.zeros((20, 20)), uv[:1], tolerance=1e-3)[0] == 0


def _ring_poses(n_images=7, seed=3):
    """Body-to-camera matrices of ``n_images`` cameras turned about y and moved, keyed by image ids with gaps."""
    rng = np.random.default_rng(seed)
    poses = {}
    for image in range(n_images):
        angle = rng.uniform(0, 2 * np.pi)
        pose = np.eye(4)
        pose[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
        pose[:3, 3] = rng.normal(size=3) * 100
        poses[2 * image + 1] = pose
    return poses


def test_rows_by_image_groups_every_row_once_in_order():
    image_index = np.array([5, 1, 5, 3, 1, 1, 5])
    groups = cloud.rows_by_image(image_index)
    assert [image for image, _ in groups] == [1, 3, 5]
    assert [rows.tolist() for _, rows in groups] == [[1, 4, 5], [3], [0, 2, 6]]


def test_in_cameras_and_rotations_of_match_the_per_row_matrices_bit_for_bit():
    # The refinement's sample arrays are turned image by image; every row must come out exactly as with its own
    # matrix (poses_of), so that the refinement's results do not depend on how the rows are grouped.
    rng = np.random.default_rng(0)
    poses = _ring_poses()
    image_index = rng.choice(sorted(poses), size=5000)
    vectors = rng.normal(size=(5000, 3)) * 50
    per_row = cloud.poses_of(poses, image_index)
    points_cam = cloud.in_cameras(vectors, image_index, poses, translate=True)
    assert np.array_equal(points_cam, np.einsum("nij,nj->ni", per_row[:, :3, :3], vectors) + per_row[:, :3, 3])
    directions_cam = cloud.in_cameras(vectors, image_index, poses, translate=False)
    assert np.array_equal(directions_cam, np.einsum("nij,nj->ni", per_row[:, :3, :3], vectors))
    rotations = cloud.rotations_of(poses, image_index)
    assert rotations.flags.c_contiguous and np.array_equal(rotations, per_row[:, :3, :3])
