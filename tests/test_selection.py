"""The observations chosen with the light estimated from them (select, fit, reselect), never the true light."""

import numpy as np
import open3d as o3d
import pytest

from asteroid_photometry.estimation import selection
from asteroid_photometry.experiments.table1 import observation_arrays, selection_columns
from asteroid_photometry.reflectance import laws
from asteroid_photometry.world import cameras, noise, observe

ALBEDO, K = 0.6, 0.8
MIN_OBSERVATIONS = 3


def sphere(radius, centre, resolution):
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution)
    return np.asarray(mesh.vertices) + centre, np.asarray(mesh.triangles)


@pytest.fixture(scope="module")
def scene():
    """A big sphere and a small moon beside it that shadows it, seen from 12 cameras round the equator."""
    big_v, big_f = sphere(100.0, np.zeros(3), 30)
    small_v, small_f = sphere(20.0, np.array([160.0, 0.0, 0.0]), 10)
    vertices = np.vstack([big_v, small_v])
    faces = np.vstack([big_f, small_f + len(big_v)])
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    centroids = tri.mean(axis=1)
    geometry = cameras.make_imaging_geometry(n_images=12, image_size=256, camera_distance_km=1.5, view_latitude_deg=0.0, body_radius_m=185.0)
    candidates = observe.candidate_geometry(vertices, faces, centroids, normals, geometry, 0.1, MIN_OBSERVATIONS)
    lit = observe.LitTest(vertices, faces, centroids, normals, geometry, candidates, min_cos_incidence=0.1)
    return dict(vertices=vertices, faces=faces, centroids=centroids, normals=normals, geometry=geometry, candidates=candidates, lit=lit)


def images_under(scene, light_dir_cam):
    """The images a direct-light renderer would make of the scene's candidate pixels: Minnaert where lit, 0 in shadow."""
    s = scene
    anywhere_lit = observe.LitTest(s["vertices"], s["faces"], s["centroids"], s["normals"], s["geometry"], s["candidates"], min_cos_incidence=1e-9)
    cand = s["candidates"]
    cos_i = np.clip(cand.normal_cam @ light_dir_cam, 0.0, None)
    cos_o = np.einsum("ij,ij->i", cand.normal_cam, cand.view_cam)
    brightness = np.where(anywhere_lit(light_dir_cam), laws.minnaert_brightness(ALBEDO, K, np.maximum(cos_i, 1e-12), cos_o), 0.0)
    size = s["geometry"].intrinsics.width
    images = [np.zeros((size, size)) for _ in range(s["geometry"].n_images)]
    for image, row, col, value in zip(cand.image_index, cand.pixel_row, cand.pixel_col, brightness):
        images[image][row, col] = value
    return images


def frames_with_light(light_dir_cam):
    return {"light_dir_cam": np.asarray(light_dir_cam).tolist(), "albedo": ALBEDO, "minnaert_k": K}


def test_candidates_need_no_light_and_hold_every_lit_observation(scene):
    s = scene
    light = cameras.light_dir_cam(20.0)
    known = observe.observation_geometry(s["vertices"], s["faces"], s["centroids"], s["normals"], s["geometry"], light, 0.1, 0.1, MIN_OBSERVATIONS)
    cand = s["candidates"]
    pairs = set(zip(cand.point_index.tolist(), cand.image_index.tolist()))
    assert set(zip(known.point_index.tolist(), known.image_index.tolist())) <= pairs
    # Candidates the light leaves out: shadowed by the moon or grazing; the lit test puts exactly those aside.
    lit = observe.enough_observations(cand.point_index, s["lit"](light), cand.n_points, MIN_OBSERVATIONS)
    assert (~lit).sum() > 20
    assert np.array_equal(cand.subset(lit).point_index, known.point_index) and np.array_equal(cand.subset(lit).image_index, known.image_index)


def test_the_selection_converges_to_what_the_true_light_selects(scene, tmp_path):
    light = cameras.light_dir_cam(20.0)
    arrays = observation_arrays(scene["candidates"], frames_with_light(light), images_under(scene, light), tmp_path, scene["lit"], MIN_OBSERVATIONS)
    columns = selection_columns(arrays)
    assert columns["selection_converged"] and columns["selection_equals_true"] and columns["selection_differences"] == 0
    assert 2 <= columns["selection_passes"] <= 1 + selection.MAX_RESELECTIONS
    assert np.degrees(np.arccos(np.clip(arrays["light_dir_cam_selection"] @ light, -1, 1))) < 1e-3
    assert (arrays["normal_cam"] @ light >= 0.1).all() and (arrays["brightness"] > 0).all()


def test_the_true_light_reaches_only_the_scoring(scene, tmp_path):
    """The same images with another light written in frames.json: the same selection, scored as differing."""
    light = cameras.light_dir_cam(20.0)
    images = images_under(scene, light)
    honest = observation_arrays(scene["candidates"], frames_with_light(light), images, tmp_path, scene["lit"], MIN_OBSERVATIONS)
    lying = observation_arrays(scene["candidates"], frames_with_light(cameras.light_dir_cam(35.0)), images, tmp_path, scene["lit"], MIN_OBSERVATIONS)
    for name in ("point_index", "image_index", "brightness", "light_dir_cam_selection", "selection_passes"):
        assert np.array_equal(honest[name], lying[name]), name
    assert honest["selection_equals_true"] and not lying["selection_equals_true"] and lying["selection_differences"] > 0


def test_a_noisy_set_selects_from_its_own_images(scene, tmp_path):
    light = cameras.light_dir_cam(20.0)
    sensor = noise.sensor_from_config({"full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12, "name": "amica12"})
    rng = np.random.default_rng(0)
    noisy = [noise.apply_sensor_noise(image, sensor, rng) for image in images_under(scene, light)]
    frames = dict(frames_with_light(light), sensor=sensor.to_dict())
    arrays = observation_arrays(scene["candidates"], frames, noisy, tmp_path, scene["lit"], MIN_OBSERVATIONS)
    assert arrays["selection_converged"]
    # A light off by the noise moves the selection by a few observations at most.
    assert arrays["selection_differences"] <= 0.01 * len(arrays["brightness"])
    assert len(arrays["variance"]) == len(arrays["brightness"])


def test_iteration_stops_when_the_selection_reproduces_itself():
    """A toy: the selection is every candidate whose level is below the light's z, the fit gives 0.3 or 0.5."""
    level = np.arange(100) / 100 + 0.005

    def fit_light(mask):
        return np.array([0.0, 0.0, 0.3 if mask.mean() < 0.3 else 0.5])

    def lit(light):
        return level < light[2]

    result = selection.select_with_estimated_light(level < 0.1, fit_light, lit)
    assert result.converged and result.passes == 3 and result.sizes == [10, 30, 50]
    assert np.array_equal(lit(result.light_dir_cam), result.mask)


def test_iteration_gives_up_after_its_reselections_and_says_so():
    """A selection that alternates never settles: stopped after max_reselections, not converged."""
    first = np.array([True, False])

    def fit_light(mask):
        return np.array([float(mask[0]), 0.0, -1.0])

    def lit(light):
        return np.array([light[0] == 0.0, light[0] != 0.0])

    result = selection.select_with_estimated_light(first, fit_light, lit, max_reselections=2)
    assert not result.converged and result.passes == 3 and len(result.sizes) == 3


def test_a_dark_pixel_stays_below_the_dark_level():
    for entry in ({"full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12}, {"full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12, "radiance_at_full_well": 10.0}):
        sensor = noise.sensor_from_config(entry)
        dark = noise.apply_sensor_noise(np.zeros(200_000), sensor, np.random.default_rng(1))
        assert 0 < dark.max() <= noise.dark_level(sensor)


def test_the_dark_floor_is_relative_without_a_sensor_and_at_least_the_noise_with_one():
    brightness = np.linspace(0.0, 0.7, 1001)
    assert observe.dark_floor(brightness) == pytest.approx(observe.DARK_FRACTION * np.percentile(brightness, 99))
    dim = noise.sensor_from_config({"full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12, "radiance_at_full_well": 10.0})
    assert observe.dark_floor(brightness, dim) == noise.dark_level(dim) > observe.dark_floor(brightness)
