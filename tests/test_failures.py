"""Failure is data, bad input is named: the stages on small rendered sets with a fault put in.

A failure of the data (blank images, too few images to reconstruct) becomes
the set's status, passed on by the later stages and shown as a table row
with its reason; a malformed input file stops the stage at once with an
error naming the file and what was expected. The workflow-level run with
faults injected between the stages is in test_workflow.py.
"""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from asteroid_photometry import estimation
from asteroid_photometry.core import failures
from asteroid_photometry.core.failures import BadInput, DataFailure
from asteroid_photometry.evaluation import metrics
from asteroid_photometry.experiments.table1 import fit_set, write_observations, write_table1
from asteroid_photometry.world import cameras
from asteroid_photometry.world.image_sets import ImageSet
from asteroid_photometry.world.images import read_rendered_images, write_linear_exr

SIZE = 16
PAPER_CSV = Path(__file__).resolve().parents[1] / "workflow" / "resources" / "paper_table1.csv"


def write_set(render_dir, images, poses, intrinsics=None):
    """A rendered set as the render stage writes it: EXR images and frames.json."""
    render_dir.mkdir(parents=True, exist_ok=True)
    intrinsics = intrinsics or cameras.Intrinsics(SIZE, SIZE, 40.0, SIZE / 2, SIZE / 2)
    entries = []
    for index, (image, pose) in enumerate(zip(images, poses)):
        name = f"image_{index:03d}.exr"
        write_linear_exr(render_dir / name, image)
        entries.append({"index": index, "file": name, "body_to_camera": np.asarray(pose).tolist()})
    frames = {
        "albedo": 0.6, "minnaert_k": 0.8, "light_dir_cam": cameras.light_dir_cam(10.0).tolist(),
        "intrinsics": intrinsics.to_dict(), "images": entries,
    }
    (render_dir / "frames.json").write_text(json.dumps(frames))
    return frames


@pytest.fixture
def small_set(tmp_path):
    rng = np.random.default_rng(0)
    poses = cameras.body_to_camera_poses(3, 5000.0)
    write_set(tmp_path / "set", [rng.uniform(0.0, 0.5, (SIZE, SIZE)) for _ in poses], poses)
    return tmp_path / "set"


def edit_frames(render_dir, change):
    frames = json.loads((render_dir / "frames.json").read_text())
    change(frames)
    (render_dir / "frames.json").write_text(json.dumps(frames))


# ---------------------------------------------------------------- bad input, named


def test_a_sound_set_reads(small_set):
    frames, images = read_rendered_images(small_set)
    assert len(images) == 3 and images[0].shape == (SIZE, SIZE) and images[0].max() > 0


@pytest.mark.parametrize("image, message", [
    (np.full((SIZE, SIZE + 4), 0.3), r"image_001\.exr: the image is 20 x 16 px, but the intrinsics in frames\.json say 16 x 16"),
    (np.where(np.eye(SIZE) > 0, np.nan, 0.3), r"image_001\.exr: 16 NaN or infinite pixels; expected finite linear radiance"),
    (np.where(np.eye(SIZE) > 0, -0.2, 0.3), r"image_001\.exr: 16 negative pixels \(lowest -0\.2\); expected linear radiance >= 0"),
])
def test_a_bad_image_is_named_with_what_was_expected(small_set, image, message):
    write_linear_exr(small_set / "image_001.exr", image)
    with pytest.raises(BadInput, match=message):
        read_rendered_images(small_set)


def test_frames_missing_an_image_is_named(small_set):
    edit_frames(small_set, lambda frames: frames["images"].pop(1))
    with pytest.raises(BadInput, match=r"frames\.json: lists 2 images but not image_001\.exr found beside it"):
        read_rendered_images(small_set)
    (small_set / "image_001.exr").unlink()
    read_rendered_images(small_set)  # two images, consistently: a smaller set, not bad input
    edit_frames(small_set, lambda frames: frames["images"].append({"index": 5, "file": "image_005.exr", "body_to_camera": np.eye(4).tolist()}))
    with pytest.raises(BadInput, match=r"image entry 2 \(image_005\.exr\): the image file .*image_005\.exr is missing"):
        read_rendered_images(small_set)


@pytest.mark.parametrize("pose, message", [
    (np.eye(4)[:3].tolist(), "must be a finite 4x4 matrix"),
    ("identity", "must be a finite 4x4 matrix"),
    (np.diag([1.0, 1.0, np.nan, 1.0]).tolist(), "must be a finite 4x4 matrix"),
    (np.diag([2.0, 1.0, 1.0, 1.0]).tolist(), "must be a rigid transform"),
    (np.diag([1.0, 1.0, -1.0, 1.0]).tolist(), "must be a rigid transform"),
])
def test_a_malformed_pose_is_named(small_set, pose, message):
    def change(frames):
        frames["images"][2]["body_to_camera"] = pose

    edit_frames(small_set, change)
    with pytest.raises(BadInput, match=rf"frames\.json: image entry 2 \(image_002\.exr\): 'body_to_camera' {message}"):
        read_rendered_images(small_set)


def test_frames_without_intrinsics_or_images_are_named(small_set):
    edit_frames(small_set, lambda frames: frames["intrinsics"].pop("width"))
    with pytest.raises(BadInput, match=r"frames\.json: expected 'intrinsics' with a positive integer 'width' and 'height'"):
        read_rendered_images(small_set)
    edit_frames(small_set, lambda frames: frames.update(intrinsics={"width": SIZE, "height": SIZE}, images=[]))
    with pytest.raises(BadInput, match=r"frames\.json: expected a non-empty list 'images'"):
        read_rendered_images(small_set)


def test_bad_input_stops_the_stage_before_any_work(small_set, tmp_path):
    """Reconstruction is the most expensive per-set stage: the bad image is named before pycolmap starts."""
    pytest.importorskip("pycolmap")
    from asteroid_photometry.experiments.mission import mission_stage
    from asteroid_photometry.experiments.table2 import match_features_stage

    mission_stage(small_set, {"name": "ideal", "prior_sigma_m": 1.0}, [], 0, 0, tmp_path / "mission", tmp_path / "truth.json")
    write_linear_exr(tmp_path / "mission" / "image_002.exr", np.full((SIZE, SIZE), np.nan))
    with pytest.raises(BadInput, match="image_002.exr"):
        match_features_stage(tmp_path / "mission", tmp_path / "features", 1, RECONSTRUCTION)
    assert not (tmp_path / "features").exists()
    # The world stage before it refuses the same bad image in a rendered set, and writes neither of its outputs.
    write_linear_exr(small_set / "image_002.exr", np.full((SIZE, SIZE), np.nan))
    with pytest.raises(BadInput, match="image_002.exr"):
        mission_stage(small_set, {"name": "ideal", "prior_sigma_m": 1.0}, [], 0, 0, tmp_path / "mission2", tmp_path / "truth2.json")
    assert not (tmp_path / "mission2").exists() and not (tmp_path / "truth2.json").exists()


# ---------------------------------------------------------------- failure is data: Table 1


def synthetic_observations_npz(path, seed=0):
    light = cameras.light_dir_cam(10.0)
    obs = estimation.synthetic_observations(300, 12, light, 0.6, 0.8, np.random.default_rng(seed))
    np.savez_compressed(
        path, point_index=obs.point_index, normal_cam=obs.normal_cam, view_cam=obs.view_cam, brightness=obs.brightness,
        n_points=obs.n_points, light_dir_cam_true=light, albedo_true=np.full(obs.n_points, 0.6), minnaert_k_true=np.full(obs.n_points, 0.8),
    )
    return path


def test_a_blank_set_is_a_table1_row_with_its_reason(small_set, tmp_path):
    for path in small_set.glob("image_*.exr"):
        write_linear_exr(path, np.zeros((SIZE, SIZE)))
    with pytest.raises(DataFailure, match="3 of 3 images are blank"):
        read_rendered_images(small_set)
    # The observe stage records it (the geometry file is never read), the fit passes it on.
    write_observations(tmp_path / "never_read.npz", small_set, tmp_path / "never_read_shape.npz", tmp_path / "never_read.json", {}, tmp_path / "blank_obs.npz")
    blank_set = ImageSet(10.0, 0.5, 0.8)
    fit_set(tmp_path / "blank_obs.npz", blank_set, "koizumi_lm", tmp_path / "blank.npz", tmp_path / "blank.json", blank_set.set_id)
    row = json.loads((tmp_path / "blank.json").read_text())
    assert row["status"] == "failed: observe: 3 of 3 images are blank (no pixel above 0: image_000.exr, image_001.exr, image_002.exr)"
    assert row["albedo_true"] == 0.5 and "albedo_est" not in row
    with np.load(tmp_path / "blank.npz") as data:
        assert str(data["status"]) == "failed" and "albedo" not in data.files

    # A sound set beside it: its row is the same with or without the failed one.
    sound_set = ImageSet(10.0, 0.6, 0.8)
    fit_set(synthetic_observations_npz(tmp_path / "obs.npz"), sound_set, "koizumi_lm", tmp_path / "ok.npz", tmp_path / "ok.json", sound_set.set_id)
    write_table1([tmp_path / "ok.json"], PAPER_CSV, tmp_path / "alone.csv", tmp_path / "alone.md")
    write_table1([tmp_path / "ok.json", tmp_path / "blank.json"], PAPER_CSV, tmp_path / "both.csv", tmp_path / "both.md")
    alone, both = (pd.read_csv(tmp_path / name).set_index("set_id") for name in ("alone.csv", "both.csv"))
    assert list(both.index) == [blank_set.set_id, sound_set.set_id]  # Table 1's order: light, k, albedo
    assert list(both.status) == [row["status"], "ok"]
    assert "fit_seconds" not in both  # timings live in fit_timing.csv
    pd.testing.assert_series_equal(both.loc[sound_set.set_id], alone.loc[sound_set.set_id], check_dtype=False)
    assert both.loc[blank_set.set_id, ["light_deg_est", "albedo_err", "k_err", "n_points"]].isna().all()
    markdown = (tmp_path / "both.md").read_text()
    assert "1 of 2 sets ok; 1 failed: light10_albedo0.5_k0.8 (observe: 3 of 3 images are blank" in markdown


def test_too_few_observations_is_a_failure_of_the_data_not_a_crash(tmp_path):
    light = cameras.light_dir_cam(10.0)
    obs = estimation.synthetic_observations(2, 12, light, 0.6, 0.8, np.random.default_rng(0))
    np.savez_compressed(
        tmp_path / "obs.npz", point_index=obs.point_index, normal_cam=obs.normal_cam, view_cam=obs.view_cam, brightness=obs.brightness,
        n_points=obs.n_points, light_dir_cam_true=light, albedo_true=np.full(2, 0.6), minnaert_k_true=np.full(2, 0.8),
    )
    image_set = ImageSet(10.0, 0.6, 0.8)
    fit_set(tmp_path / "obs.npz", image_set, "varpro", tmp_path / "fit.npz", tmp_path / "fit.json", image_set.set_id)
    status = json.loads((tmp_path / "fit.json").read_text())["status"]
    assert status.startswith("failed: fit: too few observations to fit: ") and "2 points seen at least 3 times" in status


def test_a_bug_still_fails_loudly(tmp_path):
    """Only DataFailure is recorded: anything else (here an unknown estimator) propagates."""
    image_set = ImageSet(10.0, 0.6, 0.8)
    with pytest.raises(ValueError, match="unknown estimator"):
        fit_set(synthetic_observations_npz(tmp_path / "obs.npz"), image_set, "no_such_method", tmp_path / "f.npz", tmp_path / "f.json", image_set.set_id)
    assert not (tmp_path / "f.json").exists()


def test_sweep_and_monte_carlo_tables_count_failed_sets():
    rows = pd.DataFrame([
        {"set_id": "a", "method": "varpro", "status": "ok", "light_dir_err_deg": 0.1},
        {"set_id": "b", "method": "varpro", "status": "failed: observe: 36 of 36 images are blank"},
    ])
    markdown = metrics.sweep_markdown(rows, "noise")
    assert "1 of 2 sets ok; 1 failed: b (observe: 36 of 36 images are blank)." in markdown
    assert "| b | failed: observe: 36 of 36 images are blank |" in markdown
    draw = {"noise_level": "x", "light_std_deg_bound": 1.0, "light_dir_err_deg": 0.5, "light_err_sigma": 0.5, "light_mahalanobis": 0.5, "efficiency_albedo": 1.0, "efficiency_k": 1.0}
    draws = pd.DataFrame([
        {"set_id": "a", "draw": 1, "status": "ok", **draw}, {"set_id": "a", "draw": 2, "status": "ok", **draw},
        {"set_id": "b", "draw": 1, "noise_level": "x", "status": "failed: noise_monte_carlo: 36 of 36 images are blank"},
    ])
    summary = metrics.monte_carlo_summary(draws).set_index("set_id")
    assert summary.loc["a", "status"] == "ok" and summary.loc["a", "draws"] == 2
    assert summary.loc["b", "status"].startswith("failed") and summary.loc["b", "draws"] == 0
    assert summary.loc["all", "draws"] == 2
    assert "1 of 2 sets ok; 1 failed: b (noise_monte_carlo" in metrics.monte_carlo_markdown(summary.reset_index())


def test_status_cells_and_counts():
    assert failures.table_status() == "ok" and failures.table_status("fit: x") == "failed: fit: x"
    assert failures.passed_on("reconstruct: x").reason_in("register_cloud") == "reconstruct: x"
    assert DataFailure("x").reason_in("register_cloud") == "register_cloud: x"
    table = pd.DataFrame({"set_id": ["a", "b"], "priors": ["on", "on"], "status": ["ok", "ok"]})
    assert failures.status_counts_line(table) == "2 of 2 sets ok."


# ---------------------------------------------------------------- failure is data: Table 2


@pytest.fixture(scope="module")
def four_image_set(tmp_path_factory):
    """A textured sphere seen every 90 degrees: no two images share a surface patch."""
    pytest.importorskip("pycolmap")
    from test_reconstruct import textured_sphere_images

    images, intrinsics, poses = textured_sphere_images(n_images=4, size=128)
    render_dir = tmp_path_factory.mktemp("four") / "set"
    write_set(render_dir, images, poses, intrinsics)
    return render_dir


RECONSTRUCTION = {
    "intrinsics": "fixed", "tie_point_sigma_px": 1.0, "sift_peak_threshold": 0.002, "guided_matching": False, "match_max_ratio": 0.8, "match_max_turn_deg": None,
    "min_pose_inliers": 15, "min_pose_inlier_ratio": 0.1, "min_track": 3, "min_observations_per_point": 6, "min_cos_emission": 0.2,
}


def test_too_few_images_to_reconstruct_is_a_table2_row_with_its_reason(four_image_set, tmp_path):
    from asteroid_photometry.experiments.mission import mission_stage
    from asteroid_photometry.experiments.table2 import (
        CloudStageInputs, estimate_cloud_stage, match_features_stage, reconstruct_stage, refine_stage, register_stage,
    )
    from asteroid_photometry.experiments.table2_scoring import score_cloud_stage, ScoringInputs, write_table2

    mission_dir = tmp_path / "mission"
    mission_stage(four_image_set, {"name": "ideal", "prior_sigma_m": 0.01}, [], 0, 0, mission_dir, tmp_path / "truth.json")
    match_features_stage(mission_dir, tmp_path / "features", 1, RECONSTRUCTION)
    assert json.loads((tmp_path / "features" / "status.json").read_text()) == {"status": "ok"}
    reconstruct_stage(mission_dir, tmp_path / "features", tmp_path / "model", True, RECONSTRUCTION)
    status = json.loads((tmp_path / "model" / "status.json").read_text())
    assert status["status"] == "failed" and status["reason"].startswith("reconstruct: pycolmap registered ")
    assert "of 4 images in its largest model (at least 3 needed" in status["reason"]
    # The later stages pass it on without reading anything else (the shape model here does not exist).
    register_stage(tmp_path / "model", tmp_path / "no_shape.npz", RECONSTRUCTION, tmp_path / "reg.npz", tmp_path / "reg.json")
    assert json.loads((tmp_path / "reg.json").read_text()) == {"status": "failed", "reason": status["reason"], "registration_ok": False}
    refine_stage(tmp_path / "reg.npz", tmp_path / "model", mission_dir, RECONSTRUCTION, tmp_path / "refined.npz")
    inputs = CloudStageInputs(tmp_path / "reg.npz", tmp_path / "reg.json", tmp_path / "model", mission_dir, tmp_path / "refined.npz")
    methods = ("varpro", "koizumi_lm")
    estimates = {method: tmp_path / f"estimates_{method}.npz" for method in methods}
    estimate_cloud_stage(inputs, RECONSTRUCTION, estimates)
    for path in estimates.values():  # one failed file per estimator
        with np.load(path) as data:
            assert str(data["status"]) == "failed" and str(data["reason"]) == status["reason"]
    rows = {method: tmp_path / f"row_{method}.json" for method in methods}
    score_cloud_stage(
        inputs, ScoringInputs(estimates, tmp_path / "no_shape.npz", tmp_path / "truth.json", four_image_set),
        "light10_albedo0.6_k0.8", "ideal", "on", RECONSTRUCTION, rows, {method: tmp_path / f"errors_{method}.npz" for method in methods},
    )
    for method in methods:
        assert json.loads(rows[method].read_text()) == {
            "set_id": "light10_albedo0.6_k0.8", "priors": "on", "method": method, "status": f"failed: {status['reason']}", "registration_ok": False,
            "imaging": "ideal",
        }
    row = json.loads(rows["koizumi_lm"].read_text())
    write_table2([rows["koizumi_lm"]], tmp_path / "table2.csv", tmp_path / "table2.md")
    assert pd.read_csv(tmp_path / "table2.csv").status.iloc[0] == row["status"]
    assert "0 of 1 sets ok; 1 failed: light10_albedo0.6_k0.8 (reconstruct: pycolmap registered" in (tmp_path / "table2.md").read_text()


def test_a_failed_mission_set_is_passed_on_by_the_features_and_both_reconstructions(small_set, tmp_path):
    """Blank images fail the mission set; the features stage and the reconstructions record its reason unchanged."""
    pytest.importorskip("pycolmap")
    from asteroid_photometry.experiments.mission import mission_stage
    from asteroid_photometry.experiments.table2 import match_features_stage, read_reconstruction, reconstruct_stage

    for path in small_set.glob("image_*.exr"):
        write_linear_exr(path, np.zeros((SIZE, SIZE)))
    mission_stage(small_set, {"name": "ideal", "prior_sigma_m": 1.0}, [], 0, 0, tmp_path / "mission", tmp_path / "truth.json")
    match_features_stage(tmp_path / "mission", tmp_path / "features", 1, RECONSTRUCTION)
    status = json.loads((tmp_path / "features" / "status.json").read_text())
    assert status["status"] == "failed" and status["reason"].startswith("mission: 3 of 3 images are blank")
    assert [path.name for path in (tmp_path / "features").iterdir()] == ["status.json"]
    for use_priors in (True, False):
        model_dir = tmp_path / f"model-{use_priors}"
        reconstruct_stage(tmp_path / "mission", tmp_path / "features", model_dir, use_priors, RECONSTRUCTION)
        assert json.loads((model_dir / "status.json").read_text()) == status
        with pytest.raises(DataFailure, match="mission: 3 of 3 images are blank"):
            read_reconstruction(model_dir)


def test_one_estimators_failure_on_a_cloud_leaves_the_others(tmp_path, monkeypatch):
    """The estimators of a cloud run in one job: one that fails gets its own failed file and row, the others their own."""
    from types import SimpleNamespace

    from asteroid_photometry.experiments import table2, table2_scoring

    light = cameras.light_dir_cam(10.0)
    obs = estimation.synthetic_observations(200, 12, light, 0.6, 0.8, np.random.default_rng(0))
    stage = SimpleNamespace(obs=obs, mission={}, pure=SimpleNamespace(observations=obs, refined_minnaert_k=0.8, light_dir_cam=light, refined_light_dir_cam=light, normals_tilt_freely=False))
    run_estimator = table2.run_estimator

    def failing_iwano(obs, method, **options):
        if method == "iwano_linear":
            raise DataFailure("no k for the body")
        return run_estimator(obs, method, **options)

    monkeypatch.setattr(table2, "read_cloud_stage", lambda inputs, settings: stage)
    monkeypatch.setattr(table2, "run_estimator", failing_iwano)
    methods = ("varpro", "iwano_linear", "koizumi_lm")  # the failing one between the others
    estimates = {method: tmp_path / f"{method}.npz" for method in methods}
    # The stage is read by read_cloud_stage (replaced above); no mesh light file: the refinement's light is held.
    inputs = table2.CloudStageInputs(tmp_path / "reg.npz", tmp_path / "reg.json", tmp_path / "model", tmp_path / "mission", tmp_path / "refined.npz")
    table2.estimate_cloud_stage(inputs, RECONSTRUCTION, estimates)
    monkeypatch.undo()
    with np.load(estimates["iwano_linear"]) as data:
        assert str(data["status"]) == "failed" and str(data["reason"]) == "estimate_cloud: no k for the body"
    for method in ("varpro", "koizumi_lm"):
        with np.load(estimates[method]) as data:
            assert "status" not in data.files and str(data["before_method"]) == method
            assert estimation.angle_between_deg(data["after_light_dir_cam"], light) < 0.1

    # Scored where the registration failed: the failed estimator keeps its own reason, the others get the registration's.
    (tmp_path / "reg.json").write_text(json.dumps({"status": "failed", "reason": "register: no unambiguous registration", "registration_ok": False}))
    rows = {method: tmp_path / f"{method}.json" for method in methods}
    table2_scoring.score_cloud_stage(
        inputs, table2_scoring.ScoringInputs(estimates, tmp_path / "no_shape.npz", tmp_path / "truth.json", tmp_path / "render"),
        "light10_albedo0.6_k0.8", "ideal", "on", RECONSTRUCTION, rows, {method: tmp_path / f"errors_{method}.npz" for method in methods},
    )
    statuses = {method: json.loads(rows[method].read_text())["status"] for method in methods}
    assert statuses == {
        "varpro": "failed: register: no unambiguous registration", "iwano_linear": "failed: estimate_cloud: no k for the body",
        "koizumi_lm": "failed: register: no unambiguous registration",
    }


def test_a_mission_set_holds_no_truth_and_its_truth_file_does(four_image_set, tmp_path):
    from asteroid_photometry.experiments.mission import mission_stage, read_truth
    from asteroid_photometry.world.images import mission_navigation, read_mission, read_rendered_images

    condition = {"name": "amica", "sensor_level": "amica12", "psf_fwhm_px": 1.5, "gain_sigma": 0.02, "prior_sigma_m": 10.0}
    levels = [{"name": "amica12", "full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12, "radiance_at_full_well": 1.0}]
    mission_stage(four_image_set, condition, levels, [0, 1, 2], 5, tmp_path / "mission", tmp_path / "truth.json")
    mission, images = read_mission(tmp_path / "mission")
    frames, rendered = read_rendered_images(four_image_set)
    assert not {"light_dir_cam", "albedo", "minnaert_k", "bsdf"} & set(mission) and "body_to_camera" not in json.dumps(mission)
    truth = read_truth(tmp_path / "truth.json")
    assert truth["light_dir_cam"] == frames["light_dir_cam"] and [image["body_to_camera"] for image in truth["images"]] == [image["body_to_camera"] for image in frames["images"]]
    # Degraded: the sensor's noise and the gains are there, and the truth file says which gain each image got.
    assert not np.array_equal(images[0], rendered[0]) and len(truth["gains"]) == 4 and 0.9 < min(truth["gains"]) <= max(truth["gains"]) < 1.1
    centres, sigma = mission_navigation(mission)
    assert sigma == 10.0 and centres.shape == (4, 3) and mission["sensor"]["name"] == "amica12"
    # A mission set without navigation cannot be reconstructed with priors: said so, naming the condition.
    from asteroid_photometry.core.failures import BadInput
    from asteroid_photometry.experiments.table2 import reconstruct_stage

    mission_stage(four_image_set, {"name": "lost", "prior_sigma_m": 0.0}, [], 0, 0, tmp_path / "lost", tmp_path / "lost.json")
    with pytest.raises(BadInput, match="no navigation priors .*'lost' has prior_sigma_m 0"):
        reconstruct_stage(tmp_path / "lost", tmp_path / "no_features", tmp_path / "model", True, RECONSTRUCTION)


# ---------------------------------------------------------------- disk and memory, before the run


def test_footprint_scales_with_the_pixels_and_warns_where_the_machine_falls_short(tmp_path):
    import yaml
    from asteroid_photometry.core.config import validate_config
    from asteroid_photometry.world.image_sets import image_sets
    from asteroid_photometry.core.footprint import estimate_footprint, footprint_warnings

    config = validate_config(yaml.safe_load((Path(__file__).resolve().parents[1] / "config" / "config.yaml").read_text()))
    sets = image_sets(config)
    full = estimate_footprint(config, sets, 2, 3)
    # The default run: 80 sets; 32 clean sets of 7.3 MB and 48 noisy ones of 16.4 MB are 1.0 GB of images alone.
    assert full.n_sets == 80 and 1.0e9 < full.total_disk_bytes < 2.0e9
    assert full.largest_job[0] == "refine_cloud" and "estimated footprint of this run: 1.4 GB" in full.summary()
    # A set's features and matches serve both prior settings: the second setting adds only its model.
    one = estimate_footprint(config, sets, 1, 3)
    assert one.disk_bytes["reconstructions"] < full.disk_bytes["reconstructions"] < 1.5 * one.disk_bytes["reconstructions"]
    # Table 2 under the two conditions of the default config: a noisy mission set weighs about what a noisy rendered one does.
    two = estimate_footprint(config, sets, 2, 3, conditions={"ideal": {}, "amica": {"sensor_level": "amica12"}})
    assert two.disk_bytes["reconstructions"] == pytest.approx(2 * full.disk_bytes["reconstructions"])
    assert two.disk_bytes["mission sets"] == pytest.approx(full.disk_bytes["mission sets"] * (1 + 1.74 / 0.78))
    large = estimate_footprint(dict(config, image_size=1024), sets, 2, 3)
    assert large.disk_bytes["rendered images"] == pytest.approx(4 * full.disk_bytes["rendered images"])
    assert estimate_footprint(config, sets, 0, 3).disk_bytes["reconstructions"] == 0
    assert footprint_warnings(full, tmp_path, parallel_jobs=2, memory_mb=64_000) == []
    short = footprint_warnings(full, tmp_path, parallel_jobs=1, memory_mb=500)
    assert len(short) == 1 and "the largest job (refine_cloud) needs about 786 MB of memory but this machine has 500 MB" in short[0]
    assert "16 jobs at once may need about 12576 MB" in footprint_warnings(full, tmp_path, parallel_jobs=16, memory_mb=8000)[0]
    huge = estimate_footprint(dict(config, image_size=8192, n_images=360), sets, 2, 3)
    disk = footprint_warnings(huge, tmp_path, memory_mb=1e9)
    assert len(disk) == 1 and f"of disk but {tmp_path} has" in disk[0] and "image_size" in disk[0]


@pytest.mark.parametrize("fractions, orders, reason, outliers", [
    ([0.1, 0.2, 0.05, 0.3], [(0.1, True)] * 4,
     "reconstruct: no sound model on any of 4 mapper seeds: outward fractions (0.5 needed; below, the model is depth-reversed, "
     "seen from inside) 0.10, 0.20, 0.05, 0.30; cameras' largest distance from their place in the image order round the ring, "
     "in turns between images (under 1 needed) 0.10, 0.10, 0.10, 0.10; the image order kept (needed) yes, yes, yes, yes; nor "
     "with at most 10% of a model's cameras taken out", [5]),  # depth-reversed models are not mended by taking cameras out
    ([0.1, 0.9], [(0.1, True), (0.1, True)], None, None),
    ([0.9], [(0.55, True)], None, None),  # a weak part of a sound model: a camera half a turn between images from its place, in order
    # A ring closed wrongly, then two cameras in each other's place (out of order, within a turn), then depth-reversed.
    ([0.9, 0.9, 0.2, 0.9], [(18.0, False), (0.95, False), (0.1, True), (0.1, True)], None, [5]),
    ([0.9] * 4, [(18.0, False), (2.0, True), (0.6, False), (9.0, False)],
     "reconstruct: no sound model on any of 4 mapper seeds: outward fractions (0.5 needed; below, the model is depth-reversed, "
     "seen from inside) 0.90, 0.90, 0.90, 0.90; cameras' largest distance from their place in the image order round the ring, "
     "in turns between images (under 1 needed) 18.00, 2.00, 0.60, 9.00; the image order kept (needed) no, yes, no, no; nor "
     "with at most 10% of a model's cameras taken out", None),
    # Out of order on every seed, the ring sound without one camera: the model is kept without it.
    ([0.9] * 4, [(1.61, False)] * 4, None, [5]),
])
def test_a_model_unsound_on_every_seed_is_a_failure_of_the_data(small_set, tmp_path, monkeypatch, fractions, orders, reason, outliers):
    """The mapper and both tests of a model stubbed (a real depth-reversed or wrongly closed model takes a full set): the reseeding loop and its record."""
    pytest.importorskip("pycolmap")
    from test_reconstruct import synthetic_model, synthetic_scene
    from asteroid_photometry.from_images import reconstruct as rc
    from asteroid_photometry.experiments import table2

    poses, intrinsics, points = synthetic_scene()
    seeds = []

    def mapper(matches_dir, work_dir, **kwargs):
        seeds.append(kwargs["seed"])
        model = synthetic_model(poses, intrinsics, points)
        return rc.SparseReconstruction(model, rc.model_report(model, len(poses)))

    from asteroid_photometry.experiments.mission import mission_stage

    mission_stage(small_set, {"name": "ideal", "prior_sigma_m": 1.0}, [], 0, 0, tmp_path / "mission", tmp_path / "truth.json")
    failures.write_status_json(tmp_path / "features" / "status.json")  # the matched set, never read by the stubbed mapper
    monkeypatch.setattr(table2.reconstruct, "map_matches", mapper)
    monkeypatch.setattr(table2, "outward_fraction", lambda result, min_track: fractions[len(seeds) - 1])
    monkeypatch.setattr(
        table2, "ring_order",
        lambda result, phase_deg: rc.RingOrder(0.1, True) if "images_taken_out" in result.report.settings else rc.RingOrder(*orders[len(seeds) - 1]),
    )
    monkeypatch.setattr(table2, "ring_outliers", lambda result, phase_deg: None if outliers is None else np.array(outliers))
    table2.reconstruct_stage(tmp_path / "mission", tmp_path / "features", tmp_path / "model", False, RECONSTRUCTION)
    status = json.loads((tmp_path / "model" / "status.json").read_text())
    if reason is None:
        assert seeds == list(range(len(fractions)))
        assert status == {"status": "ok"}
        report = json.loads((tmp_path / "model" / "report.json").read_text())
        attempts = report["settings"]["mapper_attempts"]
        assert [attempt["outward_fraction"] for attempt in attempts] == fractions
        assert [(attempt["ring_order_error_steps"], attempt["ring_order_kept"]) for attempt in attempts] == orders
        taken_out = orders[-1] == (1.61, False)  # no seed sound
        assert report["settings"].get("images_taken_out") == (outliers if taken_out else None)
        assert report["n_images_registered"] == len(poses) - (len(outliers) if taken_out else 0)
        if taken_out:
            assert report["settings"]["ring_after_images_taken_out"] == {
                "seed": 0, "outward_fraction": 0.9, "ring_order_error_steps": 0.1, "ring_order_kept": True,
            }
    else:
        assert seeds == list(range(table2.MAX_MAPPER_SEEDS))
        assert status == {"status": "failed", "reason": reason} and not (tmp_path / "model" / "report.json").exists()
        with pytest.raises(DataFailure, match="no sound model"):
            table2.read_reconstruction(tmp_path / "model")
