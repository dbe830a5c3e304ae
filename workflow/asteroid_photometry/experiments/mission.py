"""What a mission would know, and the truth beside it: the world stage between the renderer and the image-only path.

The renderer's output (``frames.json`` beside the images) is the world's own
record: the true pose of every image, the true light, albedo and k. Table 2
must not start from it. :func:`mission_stage` turns one rendered set into two
outputs under one imaging condition (``world.degrade.ImagingCondition``):

- the **mission set** (``mission.json`` and the images): the images as the
  condition's camera records them (``degrade_images``: PSF, per-image
  calibration error, sensor noise), the intrinsics, the order and time of
  every image, the navigation solution's camera positions in the body frame
  with their stated accuracy (the true centres plus noise of that sigma),
  and the sensor's noise model. Everything the reconstruction, the
  registration, the refinement and the estimators may read;
- the **truth** (a JSON file whose path holds ``truth``): the true poses and
  light, the gain each image was given, the seeds. Only the scoring stages
  read it (with the rendered set, for the true albedo and k).

A failed rendered set (blank images) gives a mission set and a truth file
marked failed with the reason, so that its row of Table 2 says why.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from asteroid_photometry.core import files
from asteroid_photometry.core.failures import check_status, DataFailure, record, write_status_json
from asteroid_photometry.evaluation.truth import true_light, true_poses
from asteroid_photometry.world import degrade
from asteroid_photometry.world.cameras import simulate_navigation_positions
from asteroid_photometry.world.images import MISSION_FILE, read_rendered_images, write_linear_exr
from asteroid_photometry.world.shape import ROTATION_PERIOD_H

log = logging.getLogger(__name__)


def mission_stage(render_dir, condition_entry: dict, noise_levels: list, seed, prior_seed, out_dir, out_truth) -> None:
    """The mission set of one rendered set under one imaging condition, and its truth file (module docstring).

    ``condition_entry``: an ``imaging_conditions`` entry of the config;
    ``noise_levels``: the config's, where its ``sensor_level`` is found;
    ``seed``: the degradations' seed (gains, noise); ``prior_seed``: the
    navigation noise's (each: anything ``numpy.random.default_rng`` takes).
    The images are written into a temporary directory that replaces
    ``out_dir`` when complete.
    """
    condition = degrade.condition_from_config(condition_entry)
    sensor = degrade.sensor_of(condition, noise_levels)
    part = files.partial_directory(out_dir)
    try:
        frames, images = read_rendered_images(render_dir)
    except DataFailure as failure:
        reason = record("mission", failure)
        write_status_json(part / MISSION_FILE, reason)
        files.move_into_place(part, out_dir)
        write_status_json(out_truth, reason)
        return
    degraded, gains = degrade.degrade_images(images, condition, sensor, seed)
    n_images = len(images)
    period_s = ROTATION_PERIOD_H * 3600.0 / n_images
    entries = []
    for index, (image, entry) in enumerate(zip(degraded, frames["images"])):
        write_linear_exr(part / entry["file"], image)
        entries.append({"index": index, "file": entry["file"], "time_s": index * period_s})
    poses = true_poses(frames)
    navigation = None
    if condition.prior_sigma_m > 0:
        centres = simulate_navigation_positions(poses, condition.prior_sigma_m, prior_seed)
        navigation = {"camera_centres_body_m": centres.tolist(), "sigma_m": condition.prior_sigma_m, "frame": "body"}
    mission = {
        "imaging": condition.name,
        "intrinsics": frames["intrinsics"],
        "images": entries,
        "navigation": navigation,
        "sensor": sensor.to_dict() if sensor is not None else None,
        "psf_fwhm_px": condition.psf_fwhm_px,
        "gain_sigma": condition.gain_sigma,
    }
    files.write_json(part / MISSION_FILE, mission)  # last: a set without it is incomplete
    files.move_into_place(part, out_dir)
    truth = {
        "imaging": condition.name,
        "light_dir_cam": true_light(frames).tolist(),
        "images": [{"index": index, "body_to_camera": pose.tolist()} for index, pose in enumerate(poses)],
        "gains": np.asarray(gains, dtype=float).tolist(),
        "seed": seed if isinstance(seed, int) else list(seed),
        "prior_seed": prior_seed if isinstance(prior_seed, int) else list(prior_seed),
    }
    files.write_json(out_truth, truth)
    log.info(
        "mission set %s: %d images, PSF FWHM %g px, gains %.4f to %.4f, sensor %s, navigation sigma %s m",
        condition.name, n_images, condition.psf_fwhm_px, float(np.min(gains)), float(np.max(gains)),
        sensor.name if sensor is not None else "none", condition.prior_sigma_m or "none",
    )


def read_truth(truth_json) -> dict:
    """A mission set's truth file; raises the recorded :class:`DataFailure` of a set that failed."""
    truth = json.loads(Path(truth_json).read_text())
    check_status(truth, truth_json)
    return truth
