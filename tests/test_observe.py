"""Visibility, cast shadows and pixel selection of the observations, on small synthetic bodies."""

import numpy as np
import open3d as o3d
import pytest

from asteroid_photometry.world import cameras, observe


def sphere(radius, centre, resolution):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution)
    return np.asarray(mesh.vertices) + centre, np.asarray(mesh.triangles)


def facet_table(vertices, faces):
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return tri.mean(axis=1), normals / np.linalg.norm(normals, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def two_spheres():
    """A big sphere at the origin and a small one between it and the camera of image 0 (+x)."""
    big_v, big_f = sphere(100.0, np.zeros(3), 40)
    small_v, small_f = sphere(20.0, np.array([160.0, 0.0, 0.0]), 10)
    vertices = np.vstack([big_v, small_v])
    faces = np.vstack([big_f, small_f + len(big_v)])
    centroids, normals = facet_table(vertices, faces)
    geometry = cameras.make_imaging_geometry(n_images=4, image_size=256, camera_distance_km=1.5, view_latitude_deg=0.0, body_radius_m=185.0)
    return vertices, faces, centroids, normals, geometry, len(big_f)


def observations(two_spheres, light_deg, selection="pure"):
    vertices, faces, centroids, normals, geometry, _ = two_spheres
    return observe.observation_geometry(vertices, faces, centroids, normals, geometry, cameras.light_dir_cam(light_deg), 0.1, 0.1, 1, selection)


def test_camera_of_image_0_looks_along_minus_x(two_spheres):
    geometry = two_spheres[4]
    centre = cameras.camera_centres_body(geometry.body_to_camera[:1])[0]
    assert np.allclose(centre / np.linalg.norm(centre), [1.0, 0.0, 0.0])


def test_thresholds_hold_and_pixels_are_pure(two_spheres):
    vertices, faces, _, _, geometry, _ = two_spheres
    obs = observations(two_spheres, 20.0)
    light = cameras.light_dir_cam(20.0)
    assert len(obs.point_index) > 500
    assert (obs.normal_cam @ light >= 0.1).all()
    assert ((obs.normal_cam * obs.view_cam).sum(axis=1) >= 0.1).all()
    raycaster = observe.BodyRaycaster(vertices, faces)
    for image in range(geometry.n_images):
        mine = obs.image_index == image
        corners = observe.corner_facet_ids(raycaster, geometry, image)
        rows, cols, facets = obs.pixel_row[mine], obs.pixel_col[mine], obs.point_index[mine]
        for dr, dc in [(0, 0), (0, 1), (1, 0), (1, 1)]:
            assert (corners[rows + dr, cols + dc] == facets).all()
    # At most one observation per point and image.
    pairs = obs.point_index * geometry.n_images + obs.image_index
    assert len(np.unique(pairs)) == len(pairs)


def in_cone(centroids, apex, axis_point, half_angle):
    to_facet = centroids - apex
    axis = axis_point - apex
    cos = to_facet @ axis / (np.linalg.norm(to_facet, axis=1) * np.linalg.norm(axis))
    return cos > np.cos(half_angle)


def test_occluded_facets_are_not_observed(two_spheres):
    _, _, centroids, _, geometry, n_big = two_spheres
    obs = observations(two_spheres, 0.0)
    camera = cameras.camera_centres_body(geometry.body_to_camera[:1])[0]
    small_centre = np.array([160.0, 0.0, 0.0])
    half_angle = np.arcsin(20.0 / np.linalg.norm(camera - small_centre))
    big = np.arange(len(centroids)) < n_big
    behind = big & in_cone(centroids, camera, small_centre, 0.9 * half_angle) & (centroids[:, 0] > 0)
    beside = big & ~in_cone(centroids, camera, small_centre, 1.5 * half_angle) & (centroids[:, 0] > 60)
    seen_in_0 = np.zeros(len(centroids), bool)
    seen_in_0[obs.point_index[obs.image_index == 0]] = True
    assert behind.sum() > 10
    assert not seen_in_0[behind].any()
    assert seen_in_0[beside].mean() > 0.3


def test_cast_shadow_removes_facets_that_are_visible(two_spheres):
    """With the Sun 20 deg off the camera, the small sphere's shadow falls on facets the camera sees."""
    _, _, centroids, normals, geometry, n_big = two_spheres
    obs = observations(two_spheres, 20.0)
    rotation = geometry.body_to_camera[0, :3, :3]
    light_body = rotation.T @ cameras.light_dir_cam(20.0)
    small_centre = np.array([160.0, 0.0, 0.0])
    # Facets of the big sphere whose line towards the Sun passes through the small sphere.
    to_small = small_centre - centroids
    along = to_small @ light_body
    miss_distance = np.linalg.norm(to_small - along[:, None] * light_body, axis=1)
    big = np.arange(len(centroids)) < n_big
    shadowed = big & (along > 0) & (miss_distance < 0.8 * 20.0) & (normals @ light_body > 0.3)
    seen_in_0 = np.zeros(len(centroids), bool)
    seen_in_0[obs.point_index[obs.image_index == 0]] = True
    assert shadowed.sum() > 5
    assert not seen_in_0[shadowed].any()


def test_projection_selection_keeps_more_but_mixed_pixels(two_spheres):
    pure = observations(two_spheres, 20.0, "pure")
    projection = observations(two_spheres, 20.0, "projection")
    assert len(projection.point_index) > len(pure.point_index)


def test_unknown_pixel_selection_is_refused(two_spheres):
    with pytest.raises(ValueError, match="pixel_selection"):
        observations(two_spheres, 0.0, "nearest")


def test_a_shadow_sliver_across_a_lit_facet_removes_only_the_pixels_it_covers():
    """A thin bar's shadow crosses a big facet away from its centroid and vertices: the facet test passes, the pixel test does not."""
    wall = np.array([[0.0, -100, -100], [0, 100, -100], [0, 100, 100], [0, -100, 100]])
    bar = np.array([[20.0, 18, -150], [20, 22, -150], [20, 22, 150], [20, 18, 150]])
    vertices = np.vstack([wall, bar])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    centroids, normals = facet_table(vertices, faces)
    normals[:2] *= np.sign(normals[:2, 0:1])  # the wall faces +x, towards camera 0 and the Sun
    geometry = cameras.make_imaging_geometry(n_images=4, image_size=256, camera_distance_km=1.5, view_latitude_deg=0.0, body_radius_m=185.0)
    raycaster = observe.BodyRaycaster(vertices, faces)
    light_body = np.array([1.0, 0.0, 0.0])
    assert observe.facet_unshadowed(raycaster, vertices, faces, centroids, normals, np.array([0, 1]), light_body).all()
    pose = geometry.body_to_camera[0]
    spots = np.array([[0.0, 20.0, 0.0], [0.0, -50.0, 0.0], [0.0, 20.0, 60.0], [0.0, 60.0, -30.0]])  # in the shadow, lit, in it, lit
    uv = cameras.project(spots @ pose[:3, :3].T + pose[:3, 3], geometry.intrinsics)
    cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    facet = np.where(spots[:, 2] >= spots[:, 1], 1, 0)  # the wall's second triangle holds z >= y
    lit = observe.pixel_footprint_unshadowed(raycaster, geometry, 0, rows, cols, centroids[facet], normals[facet], light_body)
    assert lit.tolist() == [False, True, False, True]
