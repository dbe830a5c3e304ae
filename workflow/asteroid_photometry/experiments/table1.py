"""File-level entry points of the workflow's stages, one per rule script.

Each function reads its inputs from files, calls the library and writes its
declared outputs, nothing else; the rule scripts in ``workflow/scripts`` are
shims over these, so a stage can be run and debugged outside Snakemake.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where a table is built: a stage's job has none to build, and pandas takes 0.45 s to import
    import pandas as pd

from asteroid_photometry import estimation
from asteroid_photometry.core import files
from asteroid_photometry.core.failures import (
    DataFailure,
    record,
    status_counts_line,
    table_status,
    write_failed_npz,
    write_status_json,
)
from asteroid_photometry.estimation import selection
from asteroid_photometry.estimation.registry import load_observations, require_observations, run_estimator
from asteroid_photometry.evaluation import metrics, truth
from asteroid_photometry.evaluation.truth import truth_from_arrays
from asteroid_photometry.reflectance import laws
from asteroid_photometry.world import cameras, noise, observe, relief, render, surface_maps
from asteroid_photometry.world.cameras import load_imaging_geometry
from asteroid_photometry.world.image_sets import ImageSet
from asteroid_photometry.world.images import read_rendered_images, write_linear_exr
from asteroid_photometry.world.shape import load_shape_npz
from asteroid_photometry.world.surface_maps import FACET_MAPS_FILE

log = logging.getLogger(__name__)


def write_imaging_geometry(shape_npz, out_json, n_images, image_size, camera_distance_km, view_latitude_deg) -> None:
    shape = load_shape_npz(shape_npz)
    body_radius_m = float(np.linalg.norm(shape["vertices_m"], axis=1).max())
    geometry = cameras.make_imaging_geometry(n_images, image_size, camera_distance_km, view_latitude_deg, body_radius_m)
    log.info(
        "%d images of %d px, camera %.3f km from the centre, field of view %.3f deg, %.3f m per pixel at the centre",
        n_images, image_size, camera_distance_km, geometry.intrinsics.fov_x_deg,
        geometry.camera_distance_m / geometry.intrinsics.focal_px,
    )
    files.write_text(out_json, geometry.to_json())


def render_set(
    shape_npz, cameras_json, image_set: ImageSet, samples_per_pixel, mitsuba_variant, out_dir, threads=None, surface_map: dict | None = None,
    light_out_of_plane_deg: float = 0.0, relief_spec: dict | None = None,
) -> None:
    """Render one set; with ``surface_map`` (a ``surface_maps`` entry) its per-facet truth goes beside the images.

    An imaging condition that renders its own sets (Table 2; its cameras come
    in ``cameras_json``) adds ``light_out_of_plane_deg``, the Sun tilted out of
    the camera's x-z plane (``cameras.tilted_light_dir_cam``), and
    ``relief_spec`` (its ``relief`` entry: ``subdivisions``, ``rms_slope_deg``,
    ``seed``), the body rendered from ``relief.relief_mesh`` of the shape
    model, each fine face with its shape-model facet's albedo and k; the
    truth (facet maps, ``frames.json``) stays on the shape model's facets.
    ``frames.json`` then records both under ``condition_render``.

    The set is rendered into a temporary directory that replaces ``out_dir``
    when complete (``files.partial_directory``).
    """
    shape = load_shape_npz(shape_npz)
    geometry = load_imaging_geometry(cameras_json)
    if threads:
        render.set_render_threads(threads)
    albedo, minnaert_k, with_maps = image_set.albedo, image_set.minnaert_k, False
    if surface_map is not None:
        keys = surface_maps.SPEC_KEYS[surface_map["kind"]]
        spec = {key: value for key, value in surface_map.items() if key in keys}
        albedo, minnaert_k = surface_maps.facet_maps(shape["centroids_m"], spec, surface_map.get("seed", 0), image_set.albedo, image_set.minnaert_k)
        with_maps = True
    vertices, faces, parent_facet, condition_record = shape["vertices_m"], shape["faces"], None, None
    if relief_spec is not None or light_out_of_plane_deg != 0.0:
        condition_record = {"view_latitude_deg": geometry.view_latitude_deg, "light_out_of_plane_deg": float(light_out_of_plane_deg), "relief": None}
    if relief_spec is not None:
        vertices, faces, parent_facet = relief.relief_mesh(
            shape["vertices_m"], shape["faces"], levels=int(relief_spec["subdivisions"]), rms_slope_deg=float(relief_spec["rms_slope_deg"]),
            seed=int(relief_spec["seed"]),
        )
        # As relief_mesh weighs it: by the face's area before the relief, its shape-model facet's over 4**subdivisions.
        slope = relief.achieved_rms_slope_deg(vertices, faces, parent_facet, shape["normals"], weights=shape["areas_m2"][parent_facet])
        condition_record["relief"] = {**relief_spec, "achieved_rms_slope_deg": slope, "faces": len(faces)}
        log.info("relief: %d faces from %d facets, RMS slope %.3f deg against them", len(faces), len(shape["faces"]), slope)
    part = files.partial_directory(out_dir)
    render.render_image_set(
        vertices, faces, geometry,
        albedo=albedo, minnaert_k=minnaert_k,
        light_dir_cam=cameras.tilted_light_dir_cam(image_set.light_angle_deg, light_out_of_plane_deg),
        spp=samples_per_pixel, out_dir=part, seed=image_set.seed, variant=mitsuba_variant,
        facet_maps_path=part / FACET_MAPS_FILE if with_maps else None,
        parent_facet=parent_facet,
    )
    if condition_record is not None:
        frames = json.loads((part / "frames.json").read_text())
        files.write_json(part / "frames.json", {**frames, "condition_render": condition_record})
    files.move_into_place(part, out_dir)


def add_noise_to_set(clean_dir, sensor_entry: dict, seed: int, out_dir) -> None:
    """The clean set's images as the sensor of ``sensor_entry`` (a ``noise_levels`` entry) records them.

    A clean set that failed (blank images) gives a noisy set marked failed:
    ``frames.json`` with the status and the reason, no images.
    """
    sensor = noise.sensor_from_config(sensor_entry)
    try:
        frames, images = read_rendered_images(clean_dir)
    except DataFailure as failure:
        part = files.partial_directory(out_dir)
        write_status_json(part / "frames.json", record("add_noise", failure))
        files.move_into_place(part, out_dir)
        return
    rng = np.random.default_rng(seed)
    n_saturated = 0
    part = files.partial_directory(out_dir)
    for image, entry in zip(images, frames["images"]):
        noisy = noise.apply_sensor_noise(image, sensor, rng)
        n_saturated += int(noise.saturated(noisy, sensor).sum())
        write_linear_exr(part / entry["file"], noisy)
    if (Path(clean_dir) / FACET_MAPS_FILE).exists():
        shutil.copy2(Path(clean_dir) / FACET_MAPS_FILE, part / FACET_MAPS_FILE)
    frames["sensor"] = sensor.to_dict()
    frames["noise_seed"] = int(seed)
    (part / "frames.json").write_text(json.dumps(frames, indent=1))
    files.move_into_place(part, out_dir)
    log.info("sensor %s on %d images (seed %d): %d saturated pixels", sensor.to_dict(), len(images), seed, n_saturated)


#: The estimator whose light selects every set's observations (select, fit, reselect; ``estimation.selection``).
#: One for all of Table 1's estimators, so that they are compared on the same observations: varpro, as it
#: weighs a noisy set's observations by their variance (the maximum-likelihood light) and needs no known k
#: (``iwano_linear`` assumes one, and its light is degrees off on a varying surface).
SELECTION_ESTIMATOR = "varpro"


def write_observation_geometry(shape_npz, cameras_json, thresholds: dict, out_npz) -> None:
    """The candidate observations of the imaging geometry: what needs no light (``observe.candidate_geometry``)."""
    shape = load_shape_npz(shape_npz)
    geometry = load_imaging_geometry(cameras_json)
    candidates = observe.candidate_geometry(
        shape["vertices_m"], shape["faces"], shape["centroids_m"], shape["normals"], geometry,
        min_cos_emission=thresholds["min_cos_emission"],
        min_observations_per_point=thresholds["min_observations_per_point"],
        pixel_selection=thresholds.get("pixel_selection", "pure"),
    )
    candidates.save(out_npz)


def load_lit_test(shape_npz, cameras_json, candidates: observe.ObservationGeometry, thresholds: dict) -> observe.LitTest:
    """The light's part of the selection (incidence cut, cast shadows) for the candidates ``candidates``."""
    shape = load_shape_npz(shape_npz)
    return observe.LitTest(
        shape["vertices_m"], shape["faces"], shape["centroids_m"], shape["normals"], load_imaging_geometry(cameras_json), candidates,
        min_cos_incidence=thresholds["min_cos_incidence"], pixel_selection=thresholds.get("pixel_selection", "pure"),
    )


def select_observations(candidates: observe.ObservationGeometry, brightness, first, usable, variance, lit: observe.LitTest, min_observations_per_point: int) -> selection.Selection:
    """The candidates' selection made with the light estimated from their own brightness (no true light).

    First the light-free selection ``first`` (a mask over the candidates),
    then, with each fitted light, the ``usable`` samples (not saturated)
    that it lights (``lit``); every selection keeps the points seen at
    least ``min_observations_per_point`` times. Fitted by
    :data:`SELECTION_ESTIMATOR`, weighted by ``variance`` when given.
    """
    n_points = candidates.n_points

    def enough(mask):
        return observe.enough_observations(candidates.point_index, mask, n_points, min_observations_per_point)

    def fit_light(mask):
        obs = estimation.Observations(
            point_index=candidates.point_index[mask], normal_cam=candidates.normal_cam[mask], view_cam=candidates.view_cam[mask],
            brightness=brightness[mask], n_points=n_points,
        )
        require_observations(obs)
        return run_estimator(obs, SELECTION_ESTIMATOR, variance=None if variance is None else variance[mask]).light_dir_cam

    return selection.select_with_estimated_light(enough(first), fit_light, lambda light: enough(usable & lit(light)))


def observation_arrays(candidates: observe.ObservationGeometry, frames: dict, images: list[np.ndarray], render_dir, lit: observe.LitTest, min_observations_per_point: int) -> dict:
    """The observations selected with the estimated light, their brightness sampled from ``images``, and the truth, as arrays.

    ``candidates`` are the light-free observations (``write_observation_geometry``);
    :func:`select_observations` chooses among them. ``frames`` is the set's
    ``frames.json``; with a ``sensor`` entry (a noisy set) saturated and
    zero samples are never selected and each observation gets its variance,
    as a real pipeline that knows its sensor would do. After the selection,
    for scoring only: the truth, and whether the true light would have
    selected the same observations.
    """
    if max(candidates.image_index, default=-1) >= len(images):
        raise DataFailure(f"the set has {len(images)} images but the imaging geometry observes image {candidates.image_index.max()}")
    brightness = observe.sample_brightness(candidates, images)
    sensor = noise.sensor_from_config(frames["sensor"]) if "sensor" in frames else None
    usable = np.ones(len(brightness), dtype=bool)
    variance = None
    if sensor is not None:
        usable = ~noise.saturated(brightness, sensor) & (brightness > 0)
        log.info("%d of %d candidate samples saturated or zero, never selected", int((~usable).sum()), len(usable))
        variance = noise.observation_variance(brightness, sensor)
    floor = observe.dark_floor(brightness[usable], sensor)
    first = usable & (brightness > floor)
    log.info("%d of %d candidate samples dark (brightness <= %.3g: cast shadow or unlit), left out of the first selection", int((usable & ~first).sum()), len(first), floor)
    chosen = select_observations(candidates, brightness, first, usable, variance, lit, min_observations_per_point)
    mask = chosen.mask
    arrays = {name: getattr(candidates, name)[mask] for name in candidates.__dataclass_fields__ if name != "n_points"}
    arrays.update(n_points=candidates.n_points, brightness=brightness[mask], selection_passes=chosen.passes,
                  selection_converged=chosen.converged, light_dir_cam_selection=chosen.light_dir_cam)
    if sensor is not None:
        arrays["variance"] = variance[mask]
        arrays["sensor_json"] = np.str_(json.dumps(sensor.to_dict()))
    elif (dark := int((brightness[mask] <= floor).sum())):
        log.warning("%d of %d selected observations are dark in the image although the estimated light says lit", dark, int(mask.sum()))
    # Scoring only, after the selection is made: the truth, and the selection the true light would make.
    light_true = truth.true_light(frames)
    agreement = metrics.selection_agreement(mask, observe.enough_observations(candidates.point_index, usable & lit(light_true), candidates.n_points, min_observations_per_point))
    albedo_true, k_true = truth.facet_albedo_and_k(frames, render_dir, np.arange(candidates.n_points))
    log.info(
        "%d observations of %d points from %d images, selected in %d passes; %s",
        int(mask.sum()), len(np.unique(arrays["point_index"])), len(images), chosen.passes,
        "the true light selects the same" if agreement["selection_equals_true"] else f"the true light's selection differs in {agreement['selection_differences']} observations",
    )
    return dict(arrays, **agreement, light_dir_cam_true=light_true, albedo_true=albedo_true, minnaert_k_true=k_true)


def selection_columns(arrays: dict) -> dict:
    """The summary columns of a set's selection: its passes, whether it converged and (scoring) whether the true light selects the same.

    None for observations made without a selection (a test's synthetic ones).
    """
    kinds = {"selection_passes": int, "selection_converged": bool, "selection_equals_true": bool, "selection_differences": int}
    return {name: kind(arrays[name]) for name, kind in kinds.items() if name in arrays}


def write_observations(geometry_npz, render_dir, shape_npz, cameras_json, thresholds: dict, out_npz) -> None:
    """The observations selected with the estimated light, their brightness and geometry (or the set's failure)."""
    try:
        frames, images = read_rendered_images(render_dir)
        candidates = observe.ObservationGeometry.load(geometry_npz)
        lit = load_lit_test(shape_npz, cameras_json, candidates, thresholds)
        arrays = observation_arrays(candidates, frames, images, render_dir, lit, thresholds["min_observations_per_point"])
    except DataFailure as failure:
        write_failed_npz(out_npz, record("observe", failure))
        return
    files.savez(out_npz, **arrays)


def failed_summary_row(set_id: str, method: str, image_set: ImageSet, reason: str) -> dict:
    """A Table 1 row of a set that could not be fitted: its design (the config's values), the status, no numbers."""
    return {
        "set_id": set_id, "method": method, "status": table_status(reason), "light_deg_true": image_set.light_angle_deg,
        "albedo_true": image_set.albedo, "k_true": image_set.minnaert_k,
        "noise_level": image_set.noise_level, "surface_map": image_set.surface_map,
    }


def fit_set(observations_npz, image_set: ImageSet, method: str, out_estimates, out_summary, set_id: str) -> None:
    """One estimator on one set: per-point estimates and the summary row (a failed set's row carries the reason)."""
    try:
        _fit_set(observations_npz, image_set, method, out_estimates, out_summary, set_id)
    except DataFailure as failure:
        reason = record("fit", failure)
        write_failed_npz(out_estimates, reason)
        files.write_json(out_summary, failed_summary_row(set_id, method, image_set, reason))


def _fit_set(observations_npz, image_set: ImageSet, method: str, out_estimates, out_summary, set_id: str) -> None:
    obs, arrays = load_observations(observations_npz)
    require_observations(obs)
    result = run_estimator(obs, method, known_k=image_set.minnaert_k, variance=arrays.get("variance"))
    log.info("%s: %s after %d iterations, %.2f s: %s", method, "converged" if result.success else "NOT converged", result.n_iterations, result.fit_seconds, result.message)
    truth = truth_from_arrays(arrays)
    row = metrics.summary_row(set_id, result, truth)
    row.update(status=table_status(), noise_level=image_set.noise_level, surface_map=image_set.surface_map, **selection_columns(arrays))
    if "sensor_json" in arrays and method != "iwano_linear":  # the bound is for per-point albedo and k
        row.update(cramer_rao_summary(obs, arrays, result))
    if getattr(result, "light_std_deg", None) is not None and np.isfinite(getattr(result, "light_std_deg", np.nan)):
        row["light_std_deg_predicted"] = float(result.light_std_deg)
    log.info("summary: %s", json.dumps(row))
    uncertainty = {
        name: value for name in ("albedo_std", "minnaert_k_std", "albedo_k_cov", "light_cov_tangent")
        if (value := getattr(result, name, None)) is not None
    }
    files.savez(
        out_estimates, light_dir_cam=result.light_dir_cam, albedo=result.albedo, minnaert_k=result.minnaert_k,
        albedo_true=arrays["albedo_true"], minnaert_k_true=arrays["minnaert_k_true"], **uncertainty,
    )
    files.write_json(out_summary, row)


def cramer_rao_summary(obs: estimation.Observations, arrays: dict, result) -> dict:
    """How the fit compares with the Cramer-Rao bound of the noisy set's own observation model."""
    from asteroid_photometry.estimation import fisher

    sensor = noise.sensor_from_config(json.loads(str(arrays["sensor_json"])))
    light_true = arrays["light_dir_cam_true"]
    albedo_true, k_true = arrays["albedo_true"], arrays["minnaert_k_true"]
    # The variance of each observation at its true brightness (the model's, not the noisy sample's).
    p = obs.point_index
    true_brightness = laws.minnaert_brightness(albedo_true[p], k_true[p], np.maximum(obs.normal_cam @ light_true, 1e-9), obs.cos_emission)
    variance = noise.observation_variance(true_brightness, sensor)
    bounds = fisher.cramer_rao_bounds(obs, light_true, albedo_true, k_true, variance)
    scores = fisher.efficiency(result, {"light_dir_cam": light_true, "albedo": albedo_true, "minnaert_k": k_true}, bounds)
    return {
        "efficiency_albedo": scores["albedo_efficiency"],
        "efficiency_k": scores["k_efficiency"],
        "light_std_deg_bound": scores["light_std_deg"],
        "light_err_sigma": scores["light_error_sigma"],
        "light_mahalanobis": scores["light_mahalanobis"],
        "albedo_std_bound_median": float(np.sqrt(np.nanmedian(bounds["albedo_var"]))),
        "k_std_bound_median": float(np.sqrt(np.nanmedian(bounds["k_var"]))),
        # What an efficient estimator's per-point RMSE would be: sqrt(mean bound variance) over the fitted points.
        "albedo_std_bound_rms": float(np.sqrt(np.nanmean(np.where(np.isfinite(result.albedo), bounds["albedo_var"], np.nan)))),
        "k_std_bound_rms": float(np.sqrt(np.nanmean(np.where(np.isfinite(result.minnaert_k), bounds["k_var"], np.nan)))),
    }


def write_table1(summary_paths, paper_csv, out_csv, out_markdown) -> None:
    import pandas as pd
    table = metrics.collect_table1(summary_paths)
    paper = pd.read_csv(paper_csv)
    files.write_csv(table, out_csv)
    files.write_text(out_markdown, metrics.table1_markdown(table, paper))
    log.info("Table 1: %s", status_counts_line(table, "rows"))


def write_table1_plots(table_csv, estimate_paths, outputs) -> None:
    import pandas as pd
    from asteroid_photometry.evaluation import plots

    table = pd.read_csv(table_csv)
    paper = pd.read_csv(Path(__file__).resolve().parents[2] / "resources" / "paper_table1.csv")
    for quantity in ("light", "albedo", "minnaert_k"):
        plots.plot_errors_against_paper(table, paper, quantity, outputs[quantity])
    estimates = {}
    for path in estimate_paths:
        path = Path(path)
        with np.load(path) as data:
            if "status" in data.files:  # a failed set: no estimates to draw
                continue
            estimates[(path.parent.name, path.stem)] = {name: data[name] for name in data.files}
    plots.plot_per_point_errors(estimates, outputs["per_point"])


def write_runtime_table(benchmark_paths, summary_paths, out_csv, out_fit_timing_csv) -> None:
    """Seconds and memory of every benchmarked job; the wall-clock seconds the fits report of themselves beside it."""
    table = metrics.runtime_table(benchmark_paths)
    files.write_csv(table, out_csv)
    files.write_csv(metrics.fit_timing_table(summary_paths), out_fit_timing_csv)
    log.info("runtime per stage (s): %s", table[table.job == "TOTAL"].set_index("stage")["seconds"].round(1).to_dict())


def write_sweep_table(summary_paths, sweep: str, out_csv, out_markdown) -> None:
    table = metrics.collect_sweep(summary_paths)
    files.write_csv(table, out_csv)
    files.write_text(out_markdown, metrics.sweep_markdown(table, sweep))
    log.info("%s sweep: %s", sweep, status_counts_line(table, "rows"))


def write_noise_plot(noise_csv, out_png) -> None:
    import pandas as pd
    from asteroid_photometry.evaluation import plots

    plots.plot_errors_against_bound(pd.read_csv(noise_csv), out_png)


def write_error_map_plot(shape_npz, estimates_npz, title, out_png) -> None:
    from asteroid_photometry.evaluation import plots

    shape = load_shape_npz(shape_npz)
    with np.load(estimates_npz) as data:
        estimates = {name: data[name] for name in data.files}
    if "status" in estimates:
        plots.plot_message(f"{title}\n\nno estimates: {estimates['reason']}", out_png)
        return
    plots.plot_error_maps_on_body(shape["centroids_m"], estimates, title, out_png)


