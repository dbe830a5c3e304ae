"""The truth, read in one place: the true light, albedo and k a set was rendered with, for scoring only.

Nothing that estimates reads this module; the stages that score call it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from asteroid_photometry.core.failures import check_status
from asteroid_photometry.evaluation import metrics
from asteroid_photometry.world.surface_maps import FACET_MAPS_FILE, load_facet_maps


def truth_from_arrays(arrays: dict) -> metrics.Truth:
    """The true light, albedo and k that ``observation_arrays`` stores beside the observations."""
    return metrics.Truth(light_dir_cam=arrays["light_dir_cam_true"], albedo=arrays["albedo_true"], minnaert_k=arrays["minnaert_k_true"])


def facet_albedo_and_k(frames: dict, render_dir, facets) -> tuple[np.ndarray, np.ndarray]:
    """The true albedo and k of the given facets: the set's surface maps where it has them, else its one value."""
    maps_path = Path(render_dir) / FACET_MAPS_FILE
    if maps_path.exists():
        albedo_map, k_map = load_facet_maps(maps_path)
        return albedo_map[facets], k_map[facets]
    return np.full(len(facets), float(frames["albedo"])), np.full(len(facets), float(frames["minnaert_k"]))


def truth_for_facets(facets, shape: dict, frames: dict, render_dir):
    """Per-point true albedo, k and normal of the given facets of the shape model, and the true light."""
    albedo, minnaert_k = facet_albedo_and_k(frames, render_dir, facets)
    return albedo, minnaert_k, shape["normals"][facets], true_light(frames)


def true_light(frames: dict) -> np.ndarray:
    """The unit vector towards the Sun, in the camera frame, that a set was rendered under."""
    return np.asarray(frames["light_dir_cam"], dtype=np.float64)


def true_poses(frames: dict) -> np.ndarray:
    """The body-to-camera pose of every image of a set, (n, 4, 4): what the renderer used, not what a mission knows."""
    return np.array([image["body_to_camera"] for image in frames["images"]], dtype=float)


def rendered_truth(render_dir) -> dict:
    """A rendered set's record (``frames.json``: true poses, light, albedo and k), read for scoring without its images."""
    path = Path(render_dir) / "frames.json"
    frames = json.loads(path.read_text())
    check_status(frames, path)
    return frames
