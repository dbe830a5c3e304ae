"""The photometric refinement of Table 2 on a faceted ball imaged by ray casting, where every answer is known.

The body is a geodesic polyhedron (flat facets of about 6 px), each pixel
takes the Minnaert brightness of the facet its centre ray hits, and the
refinement starts from a smooth sphere through it: the situation of a
Poisson surface over a faceted asteroid, at a size a test can afford.
"""

from dataclasses import replace

import numpy as np
import pytest

from asteroid_photometry import estimation
from asteroid_photometry.from_images import cloud, refine
from asteroid_photometry.world.cameras import Intrinsics, pixel_rays_cam
from synthetic_helpers import equatorial_poses

o3d = pytest.importorskip("open3d")

RADIUS = 100.0
ALBEDO, MINNAERT_K = 0.6, 0.8
LIGHT_CAM = np.array([np.sin(np.radians(10.0)), 0.0, -np.cos(np.radians(10.0))])
INTRINSICS = Intrinsics(width=160, height=160, focal_px=300.0, cx=80.0, cy=80.0)


def _polyhedron():
    mesh = o3d.geometry.TriangleMesh.create_icosahedron(radius=RADIUS).subdivide_midpoint(number_of_iterations=3)
    vertices = np.asarray(mesh.vertices)
    vertices = RADIUS * vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    triangles = np.asarray(mesh.triangles)
    normals = np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]], vertices[triangles[:, 2]] - vertices[triangles[:, 0]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals *= np.sign(np.einsum("ij,ij->i", normals, vertices[triangles].mean(axis=1)))[:, None]
    return vertices, triangles, normals


def _equatorial_poses(n_images=18, distance=6 * RADIUS):
    """Cameras on a ring in the body's equator (z up), looking at the centre; OpenCV axes."""
    return equatorial_poses(n_images, distance)


def _render(vertices, triangles, normals, poses):
    """Each pixel the brightness of the facet its centre ray hits (no mixed pixels, only edges between facets)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    v, u = np.mgrid[0:INTRINSICS.height, 0:INTRINSICS.width] + 0.5
    rays_cam = pixel_rays_cam(INTRINSICS, u.ravel(), v.ravel())
    images = []
    for index in sorted(poses):
        rotation, translation = poses[index][:3, :3], poses[index][:3, 3]
        origin = -rotation.T @ translation
        directions = rays_cam @ rotation  # camera to body: R^T d
        rays = np.hstack([np.broadcast_to(origin, directions.shape), directions]).astype(np.float32)
        facet = scene.cast_rays(o3d.core.Tensor(rays))["primitive_ids"].numpy().astype(np.int64)
        hit = facet != np.iinfo(np.uint32).max
        normal_cam = normals[np.where(hit, facet, 0)] @ rotation.T
        cos_i = np.clip(normal_cam @ LIGHT_CAM, 0.0, None)
        cos_o = np.clip(-np.einsum("ij,ij->i", normal_cam, rays_cam), 1e-6, None)
        brightness = np.where(hit & (cos_i > 0), ALBEDO * cos_i**MINNAERT_K * cos_o ** (MINNAERT_K - 1.0), 0.0)
        images.append(brightness.reshape(INTRINSICS.height, INTRINSICS.width))
    return images


@pytest.fixture(scope="module")
def faceted_ball():
    vertices, triangles, normals = _polyhedron()
    poses = _equatorial_poses()
    images = _render(vertices, triangles, normals, poses)
    sphere = o3d.geometry.TriangleMesh.create_sphere(radius=RADIUS, resolution=40)
    surface = (np.asarray(sphere.vertices), np.asarray(sphere.triangles))
    return vertices, triangles, normals, poses, images, surface


def _facet_of(points, vertices, triangles):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    return scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))["primitive_ids"].numpy().astype(np.int64)


def _longitude_error_deg(fitted, true):
    difference = np.arctan2(fitted[:, 1], fitted[:, 0]) - np.arctan2(true[:, 1], true[:, 0])
    return np.degrees(np.abs((difference + np.pi) % (2 * np.pi) - np.pi))


def _spin_axis(poses):
    return refine.spin_axis([-pose[:3, :3].T @ pose[:3, 3] for pose in poses.values()])


@pytest.fixture(scope="module")
def refined(faceted_ball):
    """The refinement under the true light, from a poor start of albedo and k, normals turning about the spin axis."""
    vertices, triangles, normals, poses, images, surface = faceted_ball
    return refine.refine_by_pure_samples(
        surface, poses, INTRINSICS, images, LIGHT_CAM, albedo=0.5, minnaert_k=1.0, n_candidates=4000, min_observations=5, axis=_spin_axis(poses),
    )


def test_spin_axis_is_the_normal_of_the_cameras_ring():
    axis = _spin_axis(_equatorial_poses())
    assert abs(abs(axis[2]) - 1.0) < 1e-12


def test_normals_turning_about_the_axis_keep_their_latitude(refined):
    # The brightness cannot see a latitude (the albedo absorbs it): the fitted normals keep the surface's.
    axis = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(refined.normals @ axis, refined.surface_normals @ axis, atol=1e-9)
    turn = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", refined.normals, refined.surface_normals), -1, 1)))
    assert np.median(turn) > 0.5  # they did turn


def test_refined_samples_are_pure_and_give_the_true_albedo_and_k(faceted_ball, refined):
    vertices, triangles, normals, poses, images, surface = faceted_ball
    pure = refined
    assert len(pure.points) >= 100, "the smooth sphere's candidates find pure, one-facet samples"
    assert pure.n_candidates == 4000 and np.all(np.abs(pure.offset_px) <= 2.0) and np.all(pure.residual <= 1e-3)
    fit = estimation.fit_koizumi_lm(pure.observations, light_init=LIGHT_CAM)
    fitted = np.isfinite(fit.albedo)
    assert fitted.sum() >= 100
    assert estimation.angle_between_deg(fit.light_dir_cam, LIGHT_CAM) < 0.05
    assert estimation.angle_between_deg(pure.refined_light_dir_cam, LIGHT_CAM) < 0.1 and abs(pure.refined_minnaert_k - MINNAERT_K) < 2e-3
    # Each albedo absorbs its normal's latitude error, cos(lat)^(2k - 1): a per-point scatter, not a bias.
    assert abs(np.mean(fit.albedo[fitted]) - ALBEDO) < 5e-3 and np.median(np.abs(fit.albedo[fitted] - ALBEDO)) < 2e-3
    k_error = fit.minnaert_k[fitted] - MINNAERT_K
    assert abs(np.mean(k_error)) < 1e-3 and np.percentile(np.abs(k_error), 90) < 2e-3
    # The brightness fixes a normal's longitude (views and Sun in the equator): the sphere's are degrees off, the fitted ones not.
    true_normals = normals[_facet_of(pure.points, vertices, triangles)]
    start = _longitude_error_deg(pure.surface_normals, true_normals)
    after = _longitude_error_deg(pure.normals, true_normals)
    assert np.median(start) > 0.5 and np.median(after) < 0.2 * np.median(start)


def _light_at(elevation_deg, azimuth_deg):
    elevation, azimuth = np.radians(elevation_deg), np.radians(azimuth_deg)
    return np.array([np.sin(azimuth) * np.cos(elevation), np.sin(elevation), -np.cos(azimuth) * np.cos(elevation)])


def _elevation_azimuth_deg(light, axis):
    """The light's elevation out of the plane normal to ``axis`` and its azimuth in it (deg, from an arbitrary origin)."""
    helper = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    helper /= np.linalg.norm(helper)
    return np.degrees(np.arcsin(light @ axis)), np.degrees(np.arctan2(light @ np.cross(axis, helper), light @ helper))


def test_keep_azimuth_takes_the_elevation_of_one_light_and_the_azimuth_of_another():
    axis = np.array([0.0, 1.0, 0.0])
    light, source = _light_at(3.0, 10.0), _light_at(-7.0, 14.0)
    kept = refine.keep_azimuth(light, source, -axis)  # the axis's sign does not matter
    assert np.isclose(np.linalg.norm(kept), 1.0)
    np.testing.assert_allclose(kept, _light_at(3.0, 14.0), atol=1e-12)


def test_refinement_runs_again_until_its_light_settles():
    """refine.refine_until_settled: a pass again while the light step moved the light at least the tolerance, up to the maximum."""
    from types import SimpleNamespace

    moves = [2.0, 0.9, 0.1, 0.05]  # how far each pass's light step moves the light (deg)

    def pass_number(number):
        return SimpleNamespace(light_dir_cam=_light_at(0.0, 0.0), refined_light_dir_cam=_light_at(moves[number - 1], 0.0), points=np.zeros((5, 3)), number=number)

    def again(last):
        return pass_number(last.number + 1)

    assert refine.refine_until_settled(pass_number(1), again, 4, 0.25).number == 3  # stops once a pass moved it less than 0.25
    assert refine.refine_until_settled(pass_number(1), again, 2, 0.25).number == 2  # or at the maximum
    assert refine.refine_until_settled(pass_number(1), again, 4, 3.0).number == 1
    assert refine.refine_until_settled(pass_number(1), again, 1, 0.0).number == 1


def test_the_ring_axis_in_the_cameras_frame_is_their_down_axis_on_an_equatorial_ring():
    axis_cam = refine.ring_axis_cam(_equatorial_poses())
    assert np.isclose(abs(axis_cam[1]), 1.0, atol=1e-9)


def test_refinement_keeps_the_azimuth_it_is_given_and_one_k_pulls_the_elevation_back(faceted_ball):
    # Normals fitted to the brightness under a light 1 deg off explain it as well as the true ones do
    # (a common turn of normals and light, and a latitude the albedo absorbs): the paper's joint fit
    # stays at the light the refinement started from. With one k for the body (the refinement's own
    # light, step 4) the elevation comes more than half way back; the azimuth does not.
    vertices, triangles, normals, poses, images, surface = faceted_ball
    for elevation, azimuth in ((1.0, 10.0), (0.0, 11.0)):
        start = _light_at(elevation, azimuth)
        pure = refine.refine_by_pure_samples(
            surface, poses, INTRINSICS, images, start, albedo=0.5, minnaert_k=1.0, n_candidates=4000, min_observations=5, axis=_spin_axis(poses),
        )
        assert len(pure.points) >= 100
        fit = estimation.fit_koizumi_lm(pure.observations, light_init=start)
        assert estimation.angle_between_deg(fit.light_dir_cam, start) < 0.1
        assert 0.9 < estimation.angle_between_deg(fit.light_dir_cam, LIGHT_CAM) < 1.1
        refined_error = estimation.angle_between_deg(pure.refined_light_dir_cam, LIGHT_CAM)
        if elevation:
            assert refined_error < 0.5
        else:
            assert 0.9 < refined_error < 1.1
        assert abs(pure.refined_minnaert_k - MINNAERT_K) < 2e-3


def test_with_normals_free_to_tilt_one_albedo_for_the_body_pulls_the_elevation_back(faceted_ball):
    # Normals free to tilt (no axis) are fitted under a light 2 deg off in elevation; an albedo per point then
    # lets them keep much of that error in the light step, one albedo for the body (the refinement's step 4
    # without an axis) does not, since it compares the brightness of points with different normals. The
    # azimuth, as with an axis, stays where it started.
    vertices, triangles, normals, poses, images, surface = faceted_ball
    for elevation, azimuth in ((2.0, 10.0), (0.0, 12.0)):
        start = _light_at(elevation, azimuth)
        pure = refine.refine_by_pure_samples(surface, poses, INTRINSICS, images, start, albedo=0.5, minnaert_k=1.0, n_candidates=4000, min_observations=5)
        assert len(pure.points) >= 100 and pure.normals_tilt_freely
        one_albedo_error = estimation.angle_between_deg(pure.refined_light_dir_cam, LIGHT_CAM)
        per_point = estimation.fit_pooled_k(pure.observations, start, 1.0, min_observations=5)
        if elevation:
            assert one_albedo_error < 0.2
            assert estimation.angle_between_deg(per_point.light_dir_cam, LIGHT_CAM) > 0.3
        else:
            assert 1.8 < one_albedo_error < 2.2
        assert abs(pure.refined_minnaert_k - MINNAERT_K) < 5e-3
        # The light is one albedo's elevation at the start's azimuth about the spin axis (refine.keep_azimuth).
        axis_cam = refine.ring_axis_cam(poses)
        one = estimation.fit_pooled_k(refine.one_albedo(pure.observations), start, 1.0, min_observations=1).light_dir_cam
        refined, started, by_one = (_elevation_azimuth_deg(light, axis_cam) for light in (pure.refined_light_dir_cam, start, one))
        assert abs(refined[0] - by_one[0]) < 1e-6 and abs(refined[1] - started[1]) < 1e-6
        assert abs(by_one[1] - started[1]) > 1e-4  # one albedo alone moves the azimuth, if only a little here
    assert refine.one_albedo(pure.observations).n_points == 1 and refine.one_albedo(pure.observations).n_obs == pure.observations.n_obs


def test_without_refinement_the_sphere_samples_give_biased_k(faceted_ball, refined):
    # The control: the same images sampled bilinearly at points of the smooth sphere with its normals.
    vertices, triangles, normals, poses, images, surface = faceted_ball
    points = surface[0]
    oriented = cloud.OrientedCloud(points, points / RADIUS, np.zeros(len(points), int))
    obs, _ = cloud.cloud_observations(oriented, poses, INTRINSICS, images, min_cos_emission=0.2, min_observations=5, surface=surface)
    plain = estimation.fit_koizumi_lm(obs, light_init=LIGHT_CAM)
    after = estimation.fit_koizumi_lm(refined.observations, light_init=LIGHT_CAM)
    plain_error = np.abs(plain.minnaert_k[np.isfinite(plain.minnaert_k)] - MINNAERT_K)
    after_error = np.abs(after.minnaert_k[np.isfinite(after.minnaert_k)] - MINNAERT_K)
    assert len(plain_error) > 1000
    assert np.median(plain_error) > 10 * np.median(after_error)


def test_refinement_needs_pure_samples(faceted_ball):
    # Images with 5 % pixel noise, so that no four neighbouring pixels agree: nothing is accepted.
    vertices, triangles, normals, poses, images, surface = faceted_ball
    rng = np.random.default_rng(0)
    noisy = [image * (1 + 0.05 * rng.standard_normal(image.shape)) for image in images]
    pure = refine.refine_by_pure_samples(surface, poses, INTRINSICS, noisy, LIGHT_CAM, albedo=0.5, minnaert_k=1.0, n_candidates=2000, min_observations=5)
    assert len(pure.points) == 0 and pure.observations.n_obs == 0
    assert np.all(np.isnan(pure.refined_light_dir_cam)) and np.isnan(pure.refined_minnaert_k)


def test_refined_cloud_round_trips_through_its_file(refined, tmp_path):
    refined.save(tmp_path / "refined.npz")
    again = refine.PureSampleCloud.load(tmp_path / "refined.npz")
    np.testing.assert_array_equal(again.points, refined.points)
    np.testing.assert_array_equal(again.observations.brightness, refined.observations.brightness)
    np.testing.assert_array_equal(again.light_dir_cam, LIGHT_CAM)
    np.testing.assert_array_equal(again.refined_light_dir_cam, refined.refined_light_dir_cam)
    assert again.refined_minnaert_k == refined.refined_minnaert_k
    assert again.n_candidates == refined.n_candidates and again.observations.n_points == len(refined.points)
    # Whether the normals tilted freely (the final fit's cut depends on it): False about an axis, kept either way.
    assert not refined.normals_tilt_freely and not again.normals_tilt_freely
    replace(refined, normals_tilt_freely=True).save(tmp_path / "free.npz")
    assert refine.PureSampleCloud.load(tmp_path / "free.npz").normals_tilt_freely
    # A file from before the flag was written says so, and how to make it again, instead of a KeyError.
    with np.load(tmp_path / "refined.npz") as data:
        np.savez(tmp_path / "older.npz", **{name: data[name] for name in data.files if name != "normals_tilt_freely"})
    with pytest.raises(ValueError, match="older version.*--forcerun refine_cloud"):
        refine.PureSampleCloud.load(tmp_path / "older.npz")


@pytest.mark.parametrize(
    "view_latitude_deg, out_of_plane_deg, expect_axis",
    [(0.0, 0.0, True), (0.0, 5.0, True), (20.0, 0.0, False), (0.0, 20.0, False), (-20.0, -20.0, False)],
)
def test_turn_axis_holds_latitudes_only_in_the_camera_rings_plane(view_latitude_deg, out_of_plane_deg, expect_axis):
    """The views' and the light's angles out of the ring's plane come back from the cameras alone; the spin axis only when both are small."""
    from asteroid_photometry.world import cameras

    poses = cameras.body_to_camera_poses(24, 5000.0, view_latitude_deg)
    light = cameras.tilted_light_dir_cam(10.0, out_of_plane_deg)
    # Any similarity frame: the reconstruction's is turned, shifted and scaled against the body's.
    turn = refine._turn(np.eye(3), np.array([0.6, 0.0, 0.8]), np.full(3, 0.7))
    frame = np.eye(4)
    frame[:3, :3], frame[:3, 3] = turn, (30.0, -20.0, 5.0)
    scale = 0.01
    moved = {}
    for i, pose in enumerate(poses):
        body_from_frame = np.linalg.inv(frame)
        m = pose @ body_from_frame
        m[:3, 3] *= scale
        moved[i] = m
    centre = scale * (frame[:3, :3] @ np.zeros(3) + frame[:3, 3])
    axis, view_deg, light_deg = refine.turn_axis(moved, centre, light)
    assert view_deg == pytest.approx(abs(view_latitude_deg), abs=0.01)
    # The light's angle to the equator, in the body frame (equal to the tilt out of the camera's x-z plane when the views are equatorial).
    light_body = poses[0, :3, :3].T @ light
    assert light_deg == pytest.approx(np.degrees(np.arcsin(abs(light_body[2]))), abs=0.01)
    if view_latitude_deg == 0.0:
        assert light_deg == pytest.approx(abs(out_of_plane_deg), abs=0.01)
    assert (axis is not None) == expect_axis
    if expect_axis:
        assert abs(abs(axis @ turn[:, 2]) - 1.0) < 1e-9  # the body's z, seen in the reconstruction's frame


def _amica12_sensor():
    from asteroid_photometry.world.noise import sensor_from_config

    return sensor_from_config({"name": "amica12", "full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12, "radiance_at_full_well": 1.0})


def test_the_residual_test_allows_the_images_calibration_scatter(faceted_ball):
    """Under a sensor and a 2 % gain per image, a residual test that knows the gains' scatter keeps more points, and
    the light step's gains from them come out closer to the truth than from the points a noise-only test keeps."""
    from asteroid_photometry.from_images.purity import PurityTest
    from asteroid_photometry.world.noise import apply_sensor_noise

    vertices, triangles, normals, poses, images, surface = faceted_ball
    sensor = _amica12_sensor()
    rng = np.random.default_rng(1)
    gains = np.exp(0.02 * rng.standard_normal(len(images)))
    recorded = [apply_sensor_noise(image * gain, sensor, rng) for image, gain in zip(images, gains)]
    purity_test, axis = PurityTest(sensor), _spin_axis(poses)

    def refined_under(gain_sigma):
        pure = refine.refine_by_pure_samples(
            surface, poses, INTRINSICS, recorded, LIGHT_CAM, albedo=0.5, minnaert_k=1.0, n_candidates=4000, min_observations=5, axis=axis,
            purity_tolerance=purity_test, max_residual=0.002, gain_sigma=gain_sigma,
        )
        relative_sd = lambda brightness: np.sqrt(purity_test.sample_variance(brightness)) / brightness  # noqa: E731
        return pure, refine.anchored_light(pure, poses, axis, relative_sd, gain_sigma=0.02, n_images=len(images), min_observations=5)

    def gain_error(estimated):
        log_ratio = np.log(estimated / gains)
        return np.std(log_ratio - log_ratio.mean())

    noise_only, noise_only_light = refined_under(0.0)
    with_gains, with_gains_light = refined_under(0.02)
    assert len(with_gains.points) >= 1.6 * len(noise_only.points)
    assert gain_error(with_gains_light.image_gains) < 0.75 * gain_error(noise_only_light.image_gains) < 0.75 * np.std(np.log(gains))
    assert abs(with_gains_light.refined_minnaert_k - MINNAERT_K) < 0.01
    assert estimation.angle_between_deg(with_gains_light.refined_light_dir_cam, LIGHT_CAM) < 0.5


def test_a_candidate_no_camera_samples_scores_inf_under_the_noise_limited_test(faceted_ball):
    """The noise-limited score divides each candidate's residual by the largest its noise explains; a candidate
    with no samples has neither, and must score inf without a RuntimeWarning from the division in a job's log."""
    import warnings

    from asteroid_photometry.from_images.purity import PurityTest

    vertices, triangles, normals, poses, images, surface = faceted_ball
    sensor = _amica12_sensor()
    seen = vertices[triangles[:60]].mean(axis=1)
    points = np.vstack([seen, [0.0, 0.0, 50 * RADIUS]])  # the last far above the cameras' ring: in no image
    point_normals = np.vstack([normals[:60], [0.0, 0.0, 1.0]])
    n_images = len(images)
    pair_point, pair_image = np.repeat(np.arange(len(points)), n_images), np.tile(np.arange(n_images), len(points))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        score, _ = refine._fit_candidates(
            points, point_normals, pair_point, pair_image, poses, INTRINSICS, images, LIGHT_CAM, 0.5, 1.0, PurityTest(sensor), 5, 30.0,
            _spin_axis(poses), 0.002,
        )
    assert np.isinf(score[-1])
    assert np.isfinite(score[:-1]).sum() >= 20


def test_the_second_pass_keeps_the_first_passs_axis_when_its_restart_leaves_the_plane(tmp_path, monkeypatch):
    """Under a sensor with gains the refinement runs twice; the cloud's estimate taken again on the gain-corrected
    images can put the light out of the ring's plane. The second pass must still turn the normals about the spin
    axis, whose light step fits the gains the result records: the axis is the first pass's, not decided again."""
    from dataclasses import dataclass

    from asteroid_photometry.experiments import table2

    @dataclass(frozen=True)
    class Passed:
        points: np.ndarray
        n_candidates: int
        image_gains: np.ndarray | None

    spin = np.array([0.0, 1.0, 0.0])
    lights = iter([np.array([0.0, 0.0, 1.0]), np.array([0.0, np.sin(0.21), np.cos(0.21)])])  # the restart: 12 deg out of the plane
    starts = []

    class Recon:
        def body_to_camera(self):
            return {}

    def estimate(obs, method, **kwargs):
        return estimation.FitResult(method, next(lights), np.array([0.5]), np.array([0.8]), 1, 40, 0.0, 1, 1, True, "", 0.0)

    def turn_axis(poses, centre, light_dir_cam):
        return (spin if abs(light_dir_cam[1]) < np.sin(np.radians(refine.IN_PLANE_LIMIT_DEG)) else None), 0.0, 0.0

    def refine_pass(surface, recon, images, purity_test, settings, start, gain_sigma, residual_gain_sigma):
        starts.append(start)
        return Passed(np.zeros((3, 3)), settings["refine_candidates"], np.full(len(images), 1.01) if start[3] is not None else None)

    np.savez(tmp_path / "registration.npz", points=np.zeros((3, 3)), normals=np.eye(3), track_length=np.ones(3))
    monkeypatch.setattr(table2, "read_reconstruction", lambda path: Recon())
    monkeypatch.setattr(table2, "read_mission", lambda path: ({"sensor": {"name": "amica12"}, "gain_sigma": 0.02}, [np.ones((4, 4))] * 3))
    monkeypatch.setattr(table2, "sensor_from_config", lambda config: None)
    monkeypatch.setattr(table2, "PurityTest", lambda sensor: (lambda *args: True))
    monkeypatch.setattr(table2.cloud_lib, "poisson_surface", lambda oriented: None)
    unit = np.tile([0.0, 0.0, 1.0], (40, 1))
    monkeypatch.setattr(table2, "cloud_observations_of", lambda *args: (estimation.Observations(np.zeros(40, int), unit, unit, np.ones(40), 1), None))
    monkeypatch.setattr(table2, "run_estimator", estimate)
    monkeypatch.setattr(table2.refine, "turn_axis", turn_axis)
    monkeypatch.setattr(table2, "_refine_pass", refine_pass)

    pure = table2._refine(tmp_path / "registration.npz", tmp_path, tmp_path, {"refine_candidates": 3000, "min_observations_per_point": 4})
    assert len(starts) == 2
    assert starts[1][0][1] > 0.2  # the second pass did start from the restart's light
    assert starts[1][3] is not None and np.allclose(starts[1][3], spin)
    np.testing.assert_allclose(pure.image_gains, 1.01**2)


def test_the_facet_turn_column_reads_a_known_lean_in_the_azimuth_columns_sense():
    """``table2_scoring.facet_turn_deg``: facets turned from their surface normals by a common 0.8 degrees about the
    body's spin axis, each with a symmetric scatter of several degrees on top, read as +0.8; and a light turned the same
    way reads as a positive azimuth error about the cameras' spin axis, so the two columns share their sense."""
    from scipy.spatial.transform import Rotation

    from asteroid_photometry.evaluation import metrics
    from asteroid_photometry.experiments.table2_scoring import BODY_SPIN_AXIS, facet_turn_deg

    rng = np.random.default_rng(5)
    lon, lat = rng.uniform(0, 2 * np.pi, 4000), np.radians(rng.uniform(-60, 60, 4000))
    surface = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=1)
    turns = np.radians(0.8 + rng.normal(0.0, 6.0, len(surface)))
    facets = Rotation.from_rotvec(turns[:, None] * BODY_SPIN_AXIS).apply(surface)
    assert facet_turn_deg(surface, facets) == pytest.approx(0.8, abs=0.25)
    assert facet_turn_deg(facets, surface) == pytest.approx(-0.8, abs=0.25)
    assert facet_turn_deg(surface, surface) == pytest.approx(0.0, abs=1e-9)

    # The same turn, seen in a camera whose frame maps the body's spin axis to its own.
    body_to_camera = Rotation.from_euler("x", -90, degrees=True).as_matrix()
    light_true = np.array([np.sin(np.radians(10.0)), 0.0, -np.cos(np.radians(10.0))])
    light_body = body_to_camera.T @ light_true
    light_turned = body_to_camera @ Rotation.from_rotvec(np.radians(0.8) * BODY_SPIN_AXIS).apply(light_body)
    azimuth, elevation = metrics.light_error_components_deg(light_turned, light_true, body_to_camera @ BODY_SPIN_AXIS)
    assert azimuth == pytest.approx(0.8, abs=1e-6)
    assert elevation == pytest.approx(0.0, abs=1e-6)


def test_over_gains_divides_each_sample_by_its_images_gain():
    rng = np.random.default_rng(3)
    n_obs, n_points = 12, 3
    image_index = np.array([0, 1, 2, 3] * 3)
    normals = rng.normal(size=(n_obs, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    obs = estimation.Observations(np.repeat(np.arange(n_points), 4), normals, normals, rng.uniform(0.1, 0.5, n_obs), n_points)
    pure = refine.PureSampleCloud(
        np.zeros((n_points, 3)), np.zeros((n_points, 3)), np.zeros((n_points, 3)), obs, image_index, np.zeros(n_points), np.zeros(n_points),
        n_points, np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, -1.0]), 0.9,
    )
    gains = np.array([1.0, 1.02, 0.97, 1.01])
    divided = pure.over_gains(gains)
    np.testing.assert_allclose(divided.observations.brightness * gains[image_index], obs.brightness)
    np.testing.assert_array_equal(divided.observations.point_index, obs.point_index)
    np.testing.assert_array_equal(divided.image_gains, gains)
    # Gains divided out before are kept: the record is their product.
    again = divided.over_gains(np.array([0.99, 1.0, 1.0, 1.03]))
    np.testing.assert_allclose(again.image_gains, gains * [0.99, 1.0, 1.0, 1.03])
    np.testing.assert_allclose(again.observations.brightness * again.image_gains[image_index], obs.brightness)
