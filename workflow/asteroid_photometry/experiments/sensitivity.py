"""What the estimator needs from the geometry: why Table 2 stops where it does.

The cloud of Table 2 misses bounds that Table 1 meets, and its truth-in fits
(``table2_scoring.oracle_rows``) point at the geometry. This stage measures, per set
and on the true geometry itself, the two ways a reconstruction's geometry
enters the estimate:

* ``pure_pixels``: Table 1's own observations (pure pixels, exact
  brightness) with every point's normal tilted by a random angle of median
  ``normal_error_deg`` towards a random direction, as a reconstruction's
  normals would be; the estimator's errors against that angle.
* ``pure_pixels_latitude`` and ``pure_pixels_longitude``: the same with
  each normal tilted only along its meridian or only along its parallel
  (``split_tilt_deg``). With the views and the Sun in the body's equatorial
  plane, as here, a normal's latitude enters its brightness only through a
  factor ``cos(lat)**(2k - 1)`` that the point's own albedo absorbs exactly:
  latitude errors cost only albedo scatter, longitude errors bias k and the
  light. A photometric fit with a free albedo per point, in turn, can
  refine only the longitude.
* ``bilinear`` and ``image_purity``: every facet's centroid with its true
  normal, seen through the true cameras and sampled and scored as the cloud
  is (``cloud.cloud_observations``, ``table2.plausible_points``): bilinearly
  wherever it projects, or only where the image itself shows the sample
  pure (``cloud.sample_pure``, no shape model needed to decide). What the sampling costs with perfect
  geometry, and whether the images alone can tell good samples from bad.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where a table is built: a stage's job has none to build, and pandas takes 0.45 s to import
    import pandas as pd

from asteroid_photometry import estimation
from asteroid_photometry.core import files
from asteroid_photometry.core.failures import DataFailure, OK, record, status_counts_line, table_status
from asteroid_photometry.estimation.registry import load_observations, require_observations, run_estimator
from asteroid_photometry.evaluation import metrics
from asteroid_photometry.evaluation.metrics import TABLE2_BOUNDS
from asteroid_photometry.evaluation.truth import true_poses, truth_from_arrays
from asteroid_photometry.from_images import cloud as cloud_lib
from asteroid_photometry.world.cameras import Intrinsics
from asteroid_photometry.world.image_sets import ImageSet
from asteroid_photometry.world.images import read_rendered_images
from asteroid_photometry.world.shape import load_shape_npz

log = logging.getLogger(__name__)

MEDIAN_ABS_STANDARD_NORMAL = 0.6744897501960817
COLUMNS = ["set_id", "status", "variant", "normal_error_deg", "normal_error_deg_median", "light_dir_err_deg", "albedo_err", "k_err", "albedo_rmse", "k_rmse", "n_points", "n_obs"]


TILT_DIRECTIONS = ("random", "latitude", "longitude")


def _east_north(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents of each normal towards increasing longitude and latitude about the body's spin axis (+z)."""
    east = np.cross([0.0, 0.0, 1.0], normals)
    length = np.linalg.norm(east, axis=1, keepdims=True)
    east = np.where(length > 1e-9, east / np.maximum(length, 1e-300), [[1.0, 0.0, 0.0]])  # at a pole any tangent will do
    return east, np.cross(normals, east)


def tilt_normals(normals: np.ndarray, median_deg: float, rng: np.random.Generator, direction: str = "random") -> tuple[np.ndarray, np.ndarray]:
    """Unit normals each tilted by ``|N(0, s)|`` degrees (median ``median_deg``).

    ``direction``: ``random`` tilts towards a uniformly random tangent
    direction; ``latitude`` and ``longitude`` only along the meridian or
    the parallel through the normal (body frame, spin axis +z), with a
    random sign. Returns the tilted normals and the tilt angles in degrees.
    The same generator state gives the same directions and relative angles
    for every ``median_deg``, so a sweep over it varies the size only.
    """
    if direction not in TILT_DIRECTIONS:
        raise ValueError(f"tilt direction {direction!r}: expected one of {TILT_DIRECTIONS}")
    normals = np.asarray(normals, dtype=float)
    east, north = _east_north(normals)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, len(normals))
    angle = np.deg2rad(median_deg) / MEDIAN_ABS_STANDARD_NORMAL * np.abs(rng.standard_normal(len(normals)))
    if direction == "random":
        towards = np.cos(azimuth)[:, None] * east + np.sin(azimuth)[:, None] * north
    else:
        sign = np.where(azimuth < np.pi, 1.0, -1.0)[:, None]
        towards = sign * (north if direction == "latitude" else east)
    tilted = np.cos(angle)[:, None] * normals + np.sin(angle)[:, None] * towards
    return tilted, np.rad2deg(angle)


def tilted_observations(arrays: dict, rotations: np.ndarray, median_deg: float, rng: np.random.Generator, min_cos_emission: float, direction: str = "random"):
    """Table 1's observations (``arrays``) with each point's normal tilted as ``tilt_normals`` does.

    ``rotations``: body-to-camera rotation of every image. Observations whose
    tilted normal faces away from the camera (``cos_o < min_cos_emission``)
    are dropped, as a pipeline that trusts its normals would drop them.
    Returns the observations and the median tilt of the points kept.
    """
    rotation = rotations[arrays["image_index"]]
    point_index = arrays["point_index"]
    normal_body = np.einsum("nji,nj->ni", rotation, arrays["normal_cam"])
    per_point = np.tile([0.0, 0.0, 1.0], (int(arrays["n_points"]), 1))  # points never observed keep a placeholder
    per_point[point_index] = normal_body
    tilted, angle = tilt_normals(per_point, median_deg, rng, direction)
    normal_cam = np.einsum("nij,nj->ni", rotation, tilted[point_index])
    keep = np.einsum("ij,ij->i", normal_cam, arrays["view_cam"]) >= min_cos_emission
    obs = estimation.Observations(
        point_index=point_index[keep], normal_cam=normal_cam[keep], view_cam=arrays["view_cam"][keep],
        brightness=arrays["brightness"][keep], n_points=int(arrays["n_points"]),
    )
    return obs, float(np.median(angle[np.unique(point_index[keep])]))


def _row(set_id, variant, normal_error_deg, measured_deg, result, truth) -> dict:
    from asteroid_photometry.experiments.table2 import plausible_points

    summary = metrics.summary_row(set_id, plausible_points(result), truth)  # scored as Table 2 scores its cloud
    row = {"set_id": set_id, "status": table_status(), "variant": variant, "normal_error_deg": normal_error_deg, "normal_error_deg_median": measured_deg}
    row.update({key: summary[key] for key in COLUMNS[5:]})
    return row


def sensitivity_set(observations_npz, render_dir, shape_npz, image_set: ImageSet, settings: dict, observation_settings: dict, cloud_settings: dict, set_id: str, out_csv) -> None:
    """One set's rows of the geometry sensitivity table (see the module docstring).

    ``observation_settings``: Table 1's (config ``observations``), for the
    tilted normals; ``cloud_settings``: Table 2's (config ``reconstruction``),
    for the true surface sampled as the cloud is. A set that failed gives one
    row with the reason as its status.
    """
    import pandas as pd
    try:
        rows = _sensitivity_rows(observations_npz, render_dir, shape_npz, image_set, settings, observation_settings, cloud_settings, set_id)
    except DataFailure as failure:
        rows = [{"set_id": set_id, "status": table_status(record("geometry_sensitivity", failure))}]
    files.write_csv(pd.DataFrame(rows, columns=COLUMNS), out_csv)


def _sensitivity_rows(observations_npz, render_dir, shape_npz, image_set: ImageSet, settings: dict, observation_settings: dict, cloud_settings: dict, set_id: str) -> list[dict]:
    from asteroid_photometry.evaluation.truth import truth_for_facets

    method = settings["estimator"]
    _, arrays = load_observations(observations_npz)
    truth = truth_from_arrays(arrays)
    frames, images = read_rendered_images(render_dir)
    rotations = true_poses(frames)[:, :3, :3]
    rows = []
    for median_deg in [0.0, *settings["normal_error_deg"]]:
        obs, measured = tilted_observations(arrays, rotations, median_deg, np.random.default_rng(image_set.seed), observation_settings["min_cos_emission"])
        rows.append(_row(set_id, "pure_pixels", median_deg, measured, run_estimator(obs, method, known_k=image_set.minnaert_k), truth))
        log.info("normals tilted by %.2f deg (median): %s", measured, rows[-1])
    for direction in ("latitude", "longitude"):
        median_deg = settings["split_tilt_deg"]
        obs, measured = tilted_observations(arrays, rotations, median_deg, np.random.default_rng(image_set.seed), observation_settings["min_cos_emission"], direction)
        rows.append(_row(set_id, f"pure_pixels_{direction}", median_deg, measured, run_estimator(obs, method, known_k=image_set.minnaert_k), truth))
        log.info("normals tilted in %s only by %.2f deg (median): %s", direction, measured, rows[-1])

    shape = load_shape_npz(shape_npz)
    vertices, faces = shape["vertices_m"], shape["faces"]
    facets = np.arange(len(faces))
    centroids = vertices[faces].mean(axis=1)
    albedo, minnaert_k, normals, light = truth_for_facets(facets, shape, frames, render_dir)
    facet_truth = metrics.Truth(light_dir_cam=light, albedo=albedo, minnaert_k=minnaert_k)
    poses = dict(enumerate(true_poses(frames)))
    surface = cloud_lib.OrientedCloud(centroids, normals, np.zeros(len(faces), dtype=int))
    for variant, tolerance in (("bilinear", None), ("image_purity", settings["purity_tolerance"])):
        obs, _ = cloud_lib.cloud_observations(
            surface, poses, Intrinsics(**frames["intrinsics"]), images,
            min_cos_emission=cloud_settings["min_cos_emission"], min_observations=cloud_settings["min_observations_per_point"],
            occlusion_tolerance=1e-3 * np.ptp(centroids, axis=0).max(), purity_tolerance=tolerance, surface=(vertices, faces),
        )
        require_observations(obs)
        rows.append(_row(set_id, variant, 0.0, 0.0, run_estimator(obs, method, known_k=image_set.minnaert_k), facet_truth))
        log.info("%s samples of the true surface: %s", variant, rows[-1])
    return rows


def write_table(csv_paths, out_csv, out_markdown, out_plot) -> None:
    import pandas as pd
    from asteroid_photometry.evaluation.plots import plot_geometry_sensitivity

    table = pd.concat([pd.read_csv(path) for path in csv_paths], ignore_index=True)
    if "status" not in table:
        table.insert(1, "status", OK)
    files.write_csv(table, out_csv)
    files.write_text(out_markdown, sensitivity_markdown(table))
    plot_geometry_sensitivity(table, out_plot)


def sensitivity_markdown(table: pd.DataFrame, bounds: dict = TABLE2_BOUNDS) -> str:
    """Median and worst errors over the sets per variant and normal error, and how many sets meet each bound."""
    lines = [
        "# What the estimator needs from the geometry",
        "",
        "`pure_pixels`: Table 1's pure observations with every normal tilted at random (median tilt in the first column);",
        "`pure_pixels_latitude`, `_longitude`: tilted along the meridian only, or along the parallel only.",
        "`bilinear`: every facet centroid with its true normal through the true cameras, sampled bilinearly as the cloud is.",
        "`image_purity`: the same, keeping only samples whose four bilinear pixels agree (decided from the image alone).",
        "",
        f"Bounds (Table 2 of the issue): light {bounds['light_dir_err_deg']} deg, |albedo err| {bounds['albedo_err']}, |k err| {bounds['k_err']}.",
        "",
        status_counts_line(table.groupby("set_id", sort=False).first().reset_index()) if "status" in table else "",
        "",
        "| variant | normal error (deg) | light err median / max (deg) | |albedo err| median / max | |k err| median / max | sets within all bounds | points (median) |",
        "|---|---|---|---|---|---|---|",
    ]
    for (variant, _), group in table.groupby(["variant", "normal_error_deg"], sort=False):
        light, albedo, k = group["light_dir_err_deg"].abs(), group["albedo_err"].abs(), group["k_err"].abs()
        within = (light <= bounds["light_dir_err_deg"]) & (albedo <= bounds["albedo_err"]) & (k <= bounds["k_err"])
        lines.append(
            f"| {variant} | {group['normal_error_deg_median'].median():.2f} | {light.median():.3f} / {light.max():.3f} "
            f"| {albedo.median():.4f} / {albedo.max():.4f} | {k.median():.4f} / {k.max():.4f} | {int(within.sum())} / {len(group)} | {int(group['n_points'].median())} |"
        )
    return "\n".join(lines) + "\n"
