"""Sparse reconstruction with pycolmap: tone mapping, pose-prior bundle adjustment, the over-fitting flag.

Synthetic inputs with known answers; the slow measurement on a rendered set
is not part of the suite (see the module docstring of ``reconstruct``).
"""

import json

import numpy as np
import pytest

pycolmap = pytest.importorskip("pycolmap")

from asteroid_photometry.world import cameras  # noqa: E402
from asteroid_photometry.from_images import reconstruct as rc  # noqa: E402
from asteroid_photometry.evaluation import quality  # noqa: E402

DISTANCE_M = 5.0  # camera distance from the body centre; the body is a unit ball of points
IMAGE_SIZE = 400
N_IMAGES = 12


def synthetic_scene(n_images=N_IMAGES, n_points=150, seed=0):
    """True poses (n, 4, 4), intrinsics and body-frame points of a turning body seen from 20 deg latitude."""
    rng = np.random.default_rng(seed)
    intrinsics = cameras.intrinsics_for_body(IMAGE_SIZE, DISTANCE_M, 1.0)
    poses = cameras.body_to_camera_poses(n_images, DISTANCE_M, view_latitude_deg=20.0)
    directions = rng.normal(size=(n_points, 3))
    points = directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(0.3, 1.0, size=(n_points, 1)) ** (1 / 3)
    return poses, intrinsics, points


def synthetic_model(poses, intrinsics, points, pixel_noise=0.0, seed=0):
    """A pycolmap model of the scene with every point seen in every image (images named as the pipeline names them)."""
    rng = np.random.default_rng(seed)
    camera = pycolmap.Camera(
        model="PINHOLE", width=intrinsics.width, height=intrinsics.height,
        params=[intrinsics.focal_px, intrinsics.focal_px, intrinsics.cx, intrinsics.cy], camera_id=1,
    )
    model = pycolmap.Reconstruction()
    model.add_camera_with_trivial_rig(camera)
    for index, pose in enumerate(poses):
        uv = cameras.project(points @ pose[:3, :3].T + pose[:3, 3], intrinsics) + rng.normal(0.0, pixel_noise, size=(len(points), 2))
        image = pycolmap.Image(
            name=rc.image_name(index), points2D=pycolmap.Point2DList([pycolmap.Point2D(xy) for xy in uv]),
            camera_id=1, image_id=index + 1,
        )
        model.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pose[:3, :]))
    for point_index, xyz in enumerate(points):
        track = pycolmap.Track()
        for index in range(len(poses)):
            track.add_element(index + 1, point_index)
        model.add_point3D(xyz, track)
    return model


def model_poses(model) -> np.ndarray:
    """(n, 4, 4) poses of the model's images in image-id order."""
    return np.array([rc.pose_matrix(model.image(image_id).cam_from_world()) for image_id in sorted(model.reg_image_ids())])


def random_similarity(rng):
    rotation = pycolmap.Rotation3d(rng.normal(size=3))
    return pycolmap.Sim3d(rotation=rotation, translation=rng.normal(size=3) * 3.0, scale=2.5)


def perturb_poses(model, rng, angle_rad=0.01, shift=0.1):
    for image_id in model.reg_image_ids():
        image = model.image(image_id)
        pose = rc.pose_matrix(image.cam_from_world())
        delta = pycolmap.Rotation3d(rng.normal(size=3) * angle_rad).matrix()
        pose[:3, :3] = delta @ pose[:3, :3]
        pose[:3, 3] += rng.normal(size=3) * shift
        image.frame.set_cam_from_world(image.camera_id, pycolmap.Rigid3d(pose[:3, :]))


def true_centres_by_image_id(poses, noise_m=0.0, seed=0):
    centres = cameras.simulate_navigation_positions(poses, noise_m, seed) if noise_m else cameras.camera_centres_body(poses)
    return centres, {index + 1: centre for index, centre in enumerate(centres)}


# ----------------------------------------------------------------------------------------------
# Tone mapping
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("curve", sorted(rc.TONE_CURVES))
def test_tone_map_is_monotone_8bit_and_saturates_at_the_reference(curve):
    linear = np.concatenate([[0.0, -0.1, np.nan], np.sort(np.random.default_rng(1).uniform(0.0, 1.4, 5000)), [2.0]])
    order = np.argsort(np.nan_to_num(linear, nan=0.0), kind="stable")
    grey = rc.tone_map(linear, reference=0.7, curve=curve)
    assert grey.dtype == np.uint8 and grey.shape == linear.shape
    assert np.all(np.diff(grey[order].astype(int)) >= 0)
    assert grey[0] == grey[1] == grey[2] == 0  # zero, negative, NaN: black
    assert np.all(grey[linear >= 0.7] == 255)
    assert len(np.unique(grey)) > 100  # the 8 bits are used


def test_reference_brightness_is_a_high_percentile_of_the_lit_pixels():
    images = [np.zeros((100, 100)), np.linspace(0.0, 1.0, 10_000).reshape(100, 100)]
    images[1][0, 0] = 50.0  # one hot pixel must not set the scale
    assert 0.99 < rc.reference_brightness(images) < 1.0
    assert rc.reference_brightness([np.zeros((4, 4))]) == 1.0
    with pytest.raises(ValueError, match="unknown tone curve"):
        rc.tone_map(images[1], 1.0, "gamma7")


# ----------------------------------------------------------------------------------------------
# Priors, alignment, report
# ----------------------------------------------------------------------------------------------


def test_simulated_navigation_positions_are_truth_plus_seeded_noise():
    poses = cameras.body_to_camera_poses(2000, 5000.0)
    truth = cameras.camera_centres_body(poses)
    first = cameras.simulate_navigation_positions(poses, 2.0, seed=3)
    np.testing.assert_array_equal(first, cameras.simulate_navigation_positions(poses, 2.0, seed=3))
    assert not np.array_equal(first, cameras.simulate_navigation_positions(poses, 2.0, seed=4))
    errors = first - truth
    assert abs(errors.mean()) < 0.1 and abs(errors.std() - 2.0) < 0.1


def test_similarity_alignment_recovers_a_known_similarity():
    rng = np.random.default_rng(2)
    source = rng.normal(size=(20, 3))
    rotation = pycolmap.Rotation3d(np.array([0.3, -1.0, 0.5])).matrix()
    target = 3.0 * source @ rotation.T + np.array([1.0, 2.0, -3.0])
    scale, estimated_rotation, translation = rc.similarity_alignment(source, target)
    assert scale == pytest.approx(3.0)
    np.testing.assert_allclose(estimated_rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(translation, [1.0, 2.0, -3.0], atol=1e-12)


def test_pose_report_flags_residuals_clearly_below_the_stated_accuracy():
    poses = cameras.body_to_camera_poses(36, 5000.0)
    noisy = cameras.simulate_navigation_positions(poses, 1.0, seed=0)
    on_truth = rc.pose_report(poses, noisy, 1.0)  # cameras where the tie points put them: residual = noise
    assert 0.8 < on_truth["cam_pos_rms_ratio"] < 1.2 and not on_truth["prior_overfit"]
    scores = quality.camera_errors(dict(enumerate(poses)), poses, noisy, "body")
    assert scores["cam_pos_true_rms_m"] == 0.0 and scores["cam_rot_true_rms_deg"] < 1e-6
    on_priors = poses.copy()
    on_priors[:, :3, 3] = -np.einsum("nij,nj->ni", poses[:, :3, :3], noisy)  # cameras moved onto their priors
    pulled = rc.pose_report(on_priors, noisy, 1.0)
    assert pulled["cam_pos_rms_m"] < 1e-9 and pulled["prior_overfit"]
    scores = quality.camera_errors(dict(enumerate(on_priors)), poses, noisy, "body")
    assert scores["cam_pos_true_rms_m"] == pytest.approx(scores["prior_pos_true_rms_m"])
    assert rc.pose_report(poses, None, None) == dict.fromkeys(on_truth)  # no priors: nothing to say without the truth


def test_pose_report_without_priors_aligns_a_similarity_frame():
    poses = cameras.body_to_camera_poses(8, 5000.0, view_latitude_deg=10.0)
    rng = np.random.default_rng(5)
    similarity = random_similarity(rng)  # model-from-body
    moved = np.array([rc.pose_matrix(similarity.transform_camera_world(pycolmap.Rigid3d(pose[:3, :]))) for pose in poses])
    report = quality.camera_errors(dict(enumerate(moved)), poses, None, "arbitrary")
    assert report["alignment_scale"] == pytest.approx(1 / 2.5)
    assert report["cam_pos_true_rms_m"] < 1e-8 and report["cam_rot_true_rms_deg"] < 1e-5
    assert quality.camera_errors(dict(enumerate(moved)), poses, None, "body")["cam_pos_true_rms_m"] > 1.0  # taken as the body frame, it is not


# ----------------------------------------------------------------------------------------------
# Bundle adjustment with position priors
# ----------------------------------------------------------------------------------------------


def test_synthetic_model_follows_our_pose_and_pixel_conventions():
    poses, intrinsics, points = synthetic_scene()
    model = synthetic_model(poses, intrinsics, points)
    assert np.abs(rc.reprojection_residuals(model)).max() < 1e-9  # pycolmap projects as cameras.project does
    result = rc.SparseReconstruction(model, rc.model_report(model, len(poses)))
    estimated = result.body_to_camera()
    assert sorted(estimated) == list(range(N_IMAGES))
    np.testing.assert_allclose(np.array([estimated[i] for i in range(N_IMAGES)]), poses, atol=1e-12)
    np.testing.assert_allclose(np.array(list(result.camera_centres().values())), cameras.camera_centres_body(poses), atol=1e-12)


def test_position_priors_pull_a_perturbed_model_back_into_the_body_frame():
    poses, intrinsics, points = synthetic_scene()
    model = synthetic_model(poses, intrinsics, points)
    rng = np.random.default_rng(7)
    model.transform(random_similarity(rng))  # an arbitrary SfM frame ...
    perturb_poses(model, rng)  # ... and wrong poses
    assert rc.rms(cameras.camera_centres_body(model_poses(model)) - cameras.camera_centres_body(poses)) > 1.0
    _, priors = true_centres_by_image_id(poses)
    summary = rc.bundle_adjust(model, priors, camera_position_sigma_m=0.01, tie_point_sigma_px=1.0)
    assert summary.is_solution_usable()
    adjusted = model_poses(model)
    assert rc.rms(cameras.camera_centres_body(adjusted) - cameras.camera_centres_body(poses)) < 1e-5 * DISTANCE_M
    np.testing.assert_allclose(adjusted[:, :3, :3], poses[:, :3, :3], atol=1e-6)
    assert rc.rms(rc.reprojection_residuals(model)) < 1e-4


def test_bundle_adjustment_without_priors_keeps_the_model_frame():
    poses, intrinsics, points = synthetic_scene()
    model = synthetic_model(poses, intrinsics, points, pixel_noise=0.3)
    before, residual_before = model_poses(model), rc.rms(rc.reprojection_residuals(model))
    rc.bundle_adjust(model, None)
    after = model_poses(model)
    assert rc.rms(cameras.camera_centres_body(after) - cameras.camera_centres_body(before)) < 0.01 * DISTANCE_M
    assert rc.rms(rc.reprojection_residuals(model)) < residual_before


@pytest.mark.parametrize(
    "camera_position_sigma_m, tie_point_sigma_px, overfit",
    [
        (0.05, 1.0, False),  # healthy: exact tie points fix the camera path, the priors only the frame
        (1e-4, 1.0, True),  # a tiny prior sigma: the priors dominate
        (0.05, 1e3, True),  # poor tie points (stated 1000 px): the priors dominate
    ],
)
def test_overfit_flag_follows_the_balance_of_priors_and_tie_points(camera_position_sigma_m, tie_point_sigma_px, overfit):
    poses, intrinsics, points = synthetic_scene()
    model = synthetic_model(poses, intrinsics, points)
    prior_centres, priors = true_centres_by_image_id(poses, noise_m=camera_position_sigma_m, seed=11)
    rc.bundle_adjust(model, priors, camera_position_sigma_m=camera_position_sigma_m, tie_point_sigma_px=tie_point_sigma_px)
    report = rc.model_report(model, len(poses), prior_centres, camera_position_sigma_m=camera_position_sigma_m, tie_point_sigma_px=tie_point_sigma_px)
    scores = quality.camera_errors(rc.SparseReconstruction(model, report).body_to_camera(), poses, prior_centres, report.world_frame)
    assert report.prior_overfit is overfit
    if overfit:
        assert report.cam_pos_rms_ratio < 0.2
    else:
        assert 0.7 < report.cam_pos_rms_ratio < 1.3
        # The tie points beat the navigation: only the 7 similarity degrees of freedom keep prior noise,
        # an RMS of about sqrt(7 / (3 n)) = 0.44 of the priors' error for n = 12.
        assert scores["cam_pos_true_rms_m"] < 0.7 * scores["prior_pos_true_rms_m"]


def test_sparse_reconstruction_round_trip_with_tracks(tmp_path):
    poses, intrinsics, points = synthetic_scene(n_points=40)
    model = synthetic_model(poses, intrinsics, points, pixel_noise=0.2, seed=3)
    prior_centres, _ = true_centres_by_image_id(poses, noise_m=0.05)
    result = rc.SparseReconstruction(model, rc.model_report(model, len(poses), prior_centres, camera_position_sigma_m=0.05, tie_point_sigma_px=1.0), prior_centres)
    result.write(tmp_path / "sparse")
    again = rc.SparseReconstruction.read(tmp_path / "sparse")
    assert again.report == result.report
    np.testing.assert_array_equal(again.prior_positions, prior_centres)
    ids, xyz = again.points3d()
    np.testing.assert_allclose(xyz, points, atol=1e-12)
    tracks = again.tracks()
    assert len(tracks["point"]) == len(points) * N_IMAGES
    # Every observation is the point's projection through its image's pose, up to the added pixel noise.
    poses_again = again.body_to_camera()
    projected = np.array([
        cameras.project(poses_again[image][:3, :3] @ xyz[point] + poses_again[image][:3, 3], again.intrinsics())
        for point, image in zip(tracks["point"], tracks["image"])
    ])
    assert rc.rms(tracks["uv"] - projected) == pytest.approx(0.2 * np.sqrt(2), rel=0.15)


def test_images_taken_out_of_a_model_leave_a_copy_adjusted_and_reported_again():
    """``without_images``: the images deregistered with their observations, the rest adjusted again (with the priors
    where the model had them) and a new report naming them; the model it came from is left as it was."""
    poses, intrinsics, points = synthetic_scene(n_points=40)
    model = synthetic_model(poses, intrinsics, points, pixel_noise=0.3, seed=2)
    for index in range(N_IMAGES):  # the first point seen in images 3 and 5 only: it goes with image 3
        if index not in (3, 5):
            model.delete_observation(index + 1, 0)
    prior_centres, _ = true_centres_by_image_id(poses, noise_m=0.05, seed=4)
    report = rc.model_report(model, len(poses), prior_centres, camera_position_sigma_m=0.05, tie_point_sigma_px=1.0, settings={"seed": 0})
    result = rc.SparseReconstruction(model, report, prior_centres)
    before = result.camera_centres()
    kept = result.without_images([7, 3])
    assert list(kept.registered_indices) == [index for index in range(N_IMAGES) if index not in (3, 7)]
    assert kept.report.n_images_registered == N_IMAGES - 2 and kept.report.n_images == N_IMAGES
    assert kept.report.settings == {"seed": 0, "images_taken_out": [3, 7]}
    assert kept.report.n_observations == (len(points) - 1) * (N_IMAGES - 2)  # the two images' observations went with them
    assert kept.report.n_points3d == len(points) - 1 and result.report.n_points3d == len(points)
    assert kept.report.world_frame == "body" and kept.report.cam_pos_rms_m is not None
    assert kept.report.cam_pos_rms_m != report.cam_pos_rms_m  # adjusted again: the priors of ten cameras, not twelve
    assert rc.rms(np.array([kept.camera_centres()[index] - before[index] for index in kept.registered_indices])) < 0.01 * DISTANCE_M
    assert result.report.n_images_registered == N_IMAGES and list(result.registered_indices) == list(range(N_IMAGES))
    assert result.camera_centres().keys() == before.keys()
    with pytest.raises(ValueError, match=r"images \[12\] are not registered"):
        result.without_images([2, 12])


def test_ring_outliers_are_the_stray_cameras_of_a_model_otherwise_sound():
    """The cameras to take out so that the rest keep the order: none for a sound ring; the stray ones, farthest first, up
    to the number allowed; none will do for a ring closed wrongly."""
    centres, phase = _ring_centres(30, 0.0, seed=6)
    registered = np.arange(1, 25)  # an arc of 24 of 30 images, as the tuning set that asked for it
    assert rc.ring_outliers(centres[registered], phase[registered], 2).size == 0
    ahead = 1.0 if rc.ring_order_residuals_deg(_moved_round(centres, 12, 0.3, 30), phase)[12] > 0 else -1.0
    # Its last two cameras fall back onto the one before them (0.6 and 1.6 turns between images back, out of order).
    stray = _moved_round(_moved_round(centres, 23, -1.0 * ahead, 30), 24, -2.0 * ahead, 30)[registered]
    assert not rc.ring_order(stray, phase[registered]).sound
    rows = rc.ring_outliers(stray, phase[registered], 2)
    assert list(registered[rows]) == [23, 24]
    assert rc.ring_order(np.delete(stray, rows, axis=0), np.delete(phase[registered], rows)).sound
    assert rc.ring_outliers(stray, phase[registered], 1) is None  # one is not enough
    doubled = centres.copy()
    doubled[2] = centres[0]  # one image placed on another's: that one
    assert list(rc.ring_outliers(doubled, phase, 3)) == [2]
    folded = centres.copy()
    folded[12:18] = centres[[29 - i for i in range(12, 18)]]  # a run bent onto the other side of the ring
    assert rc.ring_outliers(folded, phase, 3) is None
    assert not rc.ring_order(doubled[:3], phase[:3]).sound
    assert rc.ring_outliers(doubled[:3], phase[:3], 3) is None  # never fewer than three cameras left


# ----------------------------------------------------------------------------------------------
# The whole pipeline on synthetic images
# ----------------------------------------------------------------------------------------------


def textured_sphere_images(n_images=18, size=256, distance_m=4.0, seed=1):
    """Lambertian unit sphere with a multi-scale albedo texture, ray-cast; the body turns 360/n degrees per image."""
    rng = np.random.default_rng(seed)
    n_waves = 60
    frequencies = rng.normal(size=(n_waves, 3))
    magnitudes = np.exp(rng.uniform(np.log(10.0), np.log(80.0), size=n_waves))
    frequencies *= (magnitudes / np.linalg.norm(frequencies, axis=1))[:, None]
    amplitudes, phases = (10.0 / magnitudes) ** 0.5, rng.uniform(0.0, 2.0 * np.pi, n_waves)
    intrinsics = cameras.intrinsics_for_body(size, distance_m, 1.0)
    poses = cameras.body_to_camera_poses(n_images, distance_m, view_latitude_deg=20.0)
    rows, cols = np.mgrid[0:size, 0:size] + 0.5
    rays_cam = cameras.pixel_rays_cam(intrinsics, cols, rows)
    light_cam = cameras.light_dir_cam(30.0)
    images = []
    for pose in poses:
        rotation = pose[:3, :3]
        centre = -rotation.T @ pose[:3, 3]
        rays_body = rays_cam @ rotation
        half_b = rays_body @ centre
        discriminant = half_b**2 - (centre @ centre - 1.0)
        hit = discriminant > 0
        surface = centre + (-half_b - np.sqrt(np.where(hit, discriminant, 0.0)))[..., None] * rays_body
        albedo = 0.5 + 0.45 * np.tanh((np.cos(surface @ frequencies.T + phases) * amplitudes).sum(-1) / 3.0)
        images.append(np.where(hit, albedo * np.clip(surface @ (rotation.T @ light_cam), 0.0, None), 0.0))
    return images, intrinsics, poses


@pytest.fixture(scope="module")
def sphere_images():
    return textured_sphere_images()


@pytest.mark.parametrize("use_priors", [True, False])
def test_reconstruct_images_end_to_end(sphere_images, tmp_path, use_priors):
    images, intrinsics, poses = sphere_images
    result = rc.reconstruct_images(
        images, intrinsics, tmp_path / "work", prior_positions=cameras.simulate_navigation_positions(poses, 0.01, 0) if use_priors else None,
        camera_position_sigma_m=0.01, tie_point_sigma_px=1.0, num_threads=2,
    )
    report = result.report
    scores = quality.camera_errors(result.body_to_camera(), poses, result.prior_positions, report.world_frame)
    assert report.n_images_registered >= 16 and report.n_points3d > 200
    assert report.reproj_rms_px < 1.0
    assert report.world_frame == ("body" if use_priors else "arbitrary")
    # Within 2 % of the distance and 1 degree of the truth: a wrong frame convention would be off by the whole distance.
    assert scores["cam_pos_true_rms_m"] < 0.02 * 4.0 and scores["cam_rot_true_rms_deg"] < 1.0
    if use_priors:
        assert report.cam_pos_rms_m is not None and report.prior_overfit is not None
        estimated = result.body_to_camera()
        index = result.registered_indices[0]
        assert np.linalg.norm(cameras.camera_centres_body(estimated[index][None])[0] - cameras.camera_centres_body(poses[index][None])[0]) < 0.1
    else:
        assert report.cam_pos_rms_m is None and scores["alignment_scale"] > 0
    tracks = result.tracks()
    assert set(np.unique(tracks["image"])) <= set(result.registered_indices.tolist())
    assert tracks["point"].max() < report.n_points3d


def test_the_same_images_give_the_same_model_bit_for_bit(sphere_images, tmp_path):
    """Two reconstructions with two extraction threads: image ids in set order, the same cameras and points (issue 13)."""
    images, intrinsics, poses = sphere_images
    models = []
    for run in ("a", "b"):
        result = rc.reconstruct_images(images, intrinsics, tmp_path / run, num_threads=2)
        model = result.model
        assert sorted((model.image(i).name, i) for i in model.images) == [(rc.image_name(k), k + 1) for k in range(len(images))]
        models.append((result.body_to_camera(), *result.points3d()))
    (poses_a, ids_a, xyz_a), (poses_b, ids_b, xyz_b) = models
    assert poses_a.keys() == poses_b.keys() and all(np.array_equal(poses_a[k], poses_b[k]) for k in poses_a)
    assert np.array_equal(ids_a, ids_b) and np.array_equal(xyz_a, xyz_b)


def test_one_matched_set_serves_both_prior_settings_and_is_only_read(sphere_images, tmp_path):
    """map_matches copies the matched set's database; with seed 0 its model is reconstruct_images's, bit for bit."""
    images, intrinsics, poses = sphere_images
    matched = rc.match_images(images, intrinsics, tmp_path / "features")
    assert matched == json.loads((tmp_path / "features" / rc.MATCHES_FILE).read_text()) and matched["n_verified_pairs"] > 0
    assert sorted(matched["n_keypoints"]) == [rc.image_name(k) for k in range(len(images))]

    def contents():
        return {path: path.read_bytes() for path in (tmp_path / "features").rglob("*") if path.is_file()}

    before = contents()
    with_priors = rc.map_matches(
        tmp_path / "features", tmp_path / "on", prior_positions=cameras.simulate_navigation_positions(poses, 0.01, 0), camera_position_sigma_m=0.01,
    )
    without = rc.map_matches(tmp_path / "features", tmp_path / "off")
    assert contents() == before
    assert with_priors.report.world_frame == "body" and without.report.world_frame == "arbitrary"
    assert with_priors.report.cam_pos_rms_m is not None and not (tmp_path / "on" / "database.db").exists()
    for result in (with_priors, without):
        assert result.report.settings["n_verified_pairs"] == matched["n_verified_pairs"]
        assert {"features", "matching"} <= set(result.report.stage_seconds) and result.report.stage_seconds["features"] == matched["stage_seconds"]["features"]
    whole = rc.reconstruct_images(images, intrinsics, tmp_path / "whole")
    poses_whole, poses_split = whole.body_to_camera(), without.body_to_camera()
    assert poses_whole.keys() == poses_split.keys() and all(np.array_equal(poses_whole[k], poses_split[k]) for k in poses_whole)
    assert np.array_equal(whole.points3d()[1], without.points3d()[1])
    with pytest.raises(ValueError, match="matched with other settings"):
        rc.map_matches(tmp_path / "features", tmp_path / "other", features=rc.FeatureOptions(peak_threshold=0.01))


def test_verified_pairs_counts_only_pairs_the_verification_accepted(tmp_path):
    """Images with nothing in common (independent noise): every pair is matched and checked, none accepted, so 0 verified pairs."""
    rng = np.random.default_rng(3)
    images = [rng.uniform(0.2, 1.0, (160, 160)) for _ in range(4)]
    intrinsics = cameras.Intrinsics(width=160, height=160, focal_px=400.0, cx=80.0, cy=80.0)
    matched = rc.match_images(images, intrinsics, tmp_path / "features", features=rc.FeatureOptions(peak_threshold=0.002))
    assert min(matched["n_keypoints"].values()) > 50
    with pycolmap.Database.open(tmp_path / "features" / "database.db") as database:
        assert database.num_matched_image_pairs() == 6  # the pairs were matched, and looked at
    assert matched["n_verified_pairs"] == 0


def _inlier_matches(database_path) -> int:
    import pycolmap

    with pycolmap.Database.open(database_path) as database:
        _, counts = database.read_two_view_geometry_num_inliers()
    return int(np.sum(counts))


def test_guided_matching_with_a_looser_ratio_finds_more_inlier_matches(sphere_images, tmp_path):
    """The config's guided_matching and match_max_ratio reach COLMAP's matcher, are recorded, and add verified matches."""
    from asteroid_photometry.experiments.table2 import feature_options

    images, intrinsics, _ = sphere_images
    settings = {"sift_peak_threshold": rc.FeatureOptions().peak_threshold, "guided_matching": True, "match_max_ratio": 0.9, "match_max_turn_deg": None}
    guided_options = feature_options(settings)
    assert (guided_options.guided_matching, guided_options.max_ratio, guided_options.min_pose_inliers) == (True, 0.9, rc.FeatureOptions().min_pose_inliers)
    assert feature_options({**settings, "min_pose_inliers": 9, "min_pose_inlier_ratio": 0.2}).min_pose_inliers == 9
    plain = rc.match_images(images, intrinsics, tmp_path / "plain")
    guided = rc.match_images(images, intrinsics, tmp_path / "guided", features=guided_options)
    assert guided["features"]["guided_matching"] is True and guided["features"]["max_ratio"] == 0.9
    assert plain["features"]["guided_matching"] is False
    assert _inlier_matches(tmp_path / "guided" / "database.db") > _inlier_matches(tmp_path / "plain" / "database.db")


def test_rotation_pairs_are_the_images_within_the_turn_across_the_wrap():
    phase = np.arange(20) * 18.0
    pairs = rc.rotation_pairs(phase, 54.0)
    assert len(pairs) == 20 * 3  # three neighbours on each side, each pair once
    assert (0, 3) in pairs and (0, 17) in pairs and (0, 4) not in pairs and (0, 16) not in pairs  # across 360 deg to 0
    assert all(i < j for i, j in pairs)
    with pytest.raises(ValueError, match="image 0 has no other image within 10 deg"):
        rc.rotation_pairs(phase, 10.0)


def _ring_centres(n_images, latitude_deg, seed):
    """Camera centres of a ring of ``n_images`` seen from ``latitude_deg``, under a random similarity, with their phases."""
    rng = np.random.default_rng(seed)
    centres = cameras.camera_centres_body(cameras.body_to_camera_poses(n_images, 5000.0, view_latitude_deg=latitude_deg))
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    return 0.003 * centres @ rotation.T + rng.normal(size=3), np.arange(n_images) * 360.0 / n_images


@pytest.mark.parametrize("n_images, latitude_deg", [(36, 0.0), (20, 20.0), (72, -35.0)])
def test_ring_order_holds_for_cameras_in_time_order_in_any_frame(n_images, latitude_deg):
    """A sound ring, in an arbitrary similarity frame, either way round, with cameras missing or only an arc of it: within the tolerance."""
    centres, phase = _ring_centres(n_images, latitude_deg, seed=n_images)
    step = 360.0 / n_images
    assert rc.ring_step_deg(phase) == pytest.approx(step)
    assert rc.ring_order(centres, phase).error_steps < 1e-6
    assert rc.ring_order(centres, -phase).error_steps < 1e-6  # the other direction of travel
    kept = np.ones(n_images, dtype=bool)
    kept[[1, 2, n_images // 2]] = False  # images the mapper did not register
    assert rc.ring_order(centres[kept], phase[kept]).error_steps < 1e-6
    arc = slice(0, n_images // 3 + 1)  # a third of the ring: the circle is fitted, not taken about the centroid
    assert rc.ring_order(centres[arc], phase[arc]).error_steps < 1e-6
    # Each camera moved by a tenth of the spacing between cameras: within tolerance, but seen.
    rng = np.random.default_rng(1)
    spacing = np.linalg.norm(centres[1] - centres[0])
    jitter = rng.normal(size=centres.shape)
    jittered = centres + 0.1 * spacing * jitter / np.linalg.norm(jitter, axis=1, keepdims=True)
    assert 0.01 < rc.ring_order(jittered, phase).error_steps < 0.5
    for ring, phases in ((centres, phase), (centres, -phase), (centres[kept], phase[kept]), (centres[arc], phase[arc]), (jittered, phase)):
        assert rc.ring_order(ring, phases).sound


def _moved_round(centres, index, steps, n_images):
    """``centres`` with camera ``index`` moved round the ring (the circle through the centres) by ``steps`` turns between images."""
    from scipy.spatial.transform import Rotation

    middle = centres.mean(axis=0)
    axis = np.linalg.svd(centres - middle)[2][2]
    moved = centres.copy()
    moved[index] = middle + Rotation.from_rotvec(np.radians(steps * 360.0 / n_images) * axis).apply(centres[index] - middle)
    return moved


def test_ring_order_passes_a_weak_part_of_a_sound_model():
    """Two neighbours out of place but in order, as a weakly tied part of a model leaves them (a tuning set at 30 images a
    turn: 0.35 back and 0.55 ahead): sound. The same two moved past each other: out of order."""
    centres, phase = _ring_centres(30, 0.0, seed=4)
    ahead = 1.0 if rc.ring_order_residuals_deg(_moved_round(centres, 26, 0.3, 30), phase)[26] > 0 else -1.0  # the way the cameras go
    weak = _moved_round(_moved_round(centres, 25, -0.35 * ahead, 30), 26, 0.55 * ahead, 30)
    ring = rc.ring_order(weak, phase)
    assert ring.order_kept and ring.error_steps == pytest.approx(0.55, abs=0.05) and ring.sound
    crossed = _moved_round(_moved_round(centres, 25, 0.6 * ahead, 30), 26, -0.6 * ahead, 30)
    ring = rc.ring_order(crossed, phase)
    assert not ring.order_kept and ring.error_steps < rc.RING_ORDER_TOLERANCE_STEPS and not ring.sound


def test_ring_order_fails_for_a_ring_closed_wrongly_and_for_swapped_images():
    centres, phase = _ring_centres(36, 0.0, seed=3)
    folded = centres.copy()
    folded[18:24] = centres[[35 - i for i in range(18, 24)]]  # a run bent onto the other side of the ring
    assert rc.ring_order(folded, phase).error_steps > 5.0
    assert not rc.ring_order(folded, phase).order_kept and not rc.ring_order(folded, phase).sound
    swapped = centres.copy()
    swapped[[10, 11]] = centres[[11, 10]]  # two neighbours in each other's place: one step each
    assert rc.ring_order(swapped, phase).error_steps == pytest.approx(1.0, abs=0.1)
    assert not rc.ring_order(swapped, phase).order_kept and not rc.ring_order(swapped, phase).sound
    doubled = centres.copy()
    doubled[2] = centres[0]  # one image placed on another's, two before it (a tuning set: 1.9 turns between images)
    assert rc.ring_order(doubled, phase).error_steps == pytest.approx(2.0, abs=0.1)
    assert not rc.ring_order(doubled, phase).order_kept and not rc.ring_order(doubled, phase).sound
    with pytest.raises(ValueError, match="at least 3 cameras"):
        rc.ring_order(centres[:2], phase[:2]).error_steps
    with pytest.raises(ValueError, match="two distinct rotation phases"):
        rc.ring_step_deg([5.0, 365.0])


def test_matching_by_rotation_matches_only_the_neighbours_and_keeps_the_model(sphere_images, tmp_path):
    """With match_max_turn_deg only the pairs within that turn are matched (and recorded); the set still reconstructs."""
    from asteroid_photometry.experiments.table2 import feature_options, rotation_phase_deg

    images, intrinsics, _ = sphere_images
    settings = {"sift_peak_threshold": rc.FeatureOptions().peak_threshold, "guided_matching": False, "match_max_ratio": 0.8, "match_max_turn_deg": 45.0}
    mission = {"images": [{"time_s": index * 3600.0 * 12.132 / len(images)} for index in range(len(images))]}
    phase = rotation_phase_deg(mission)
    np.testing.assert_allclose(phase, np.arange(len(images)) * 360.0 / len(images))
    matched = rc.match_images(images, intrinsics, tmp_path / "near", features=feature_options(settings), phase_deg=phase)
    assert matched["features"]["max_turn_deg"] == 45.0 and matched["n_pairs_matched"] == 2 * len(images)  # 20 deg steps: 2 a side
    with pycolmap.Database.open(tmp_path / "near" / "database.db") as database:
        assert database.num_matched_image_pairs() == 2 * len(images)
    assert 0 < matched["n_verified_pairs"] <= 2 * len(images)
    model = rc.map_matches(tmp_path / "near", tmp_path / "map", features=feature_options(settings))
    assert model.report.n_images_registered >= 16
    with pytest.raises(ValueError, match="needs the rotation phase of each"):
        rc.match_images(images, intrinsics, tmp_path / "none", features=feature_options(settings))
