"""Table 2 from images alone: reconstruct, register, estimate, refine; the file-level stages.

Each function reads files, calls the library (``reconstruct``, ``cloud``,
``register``, ``quality``, ``estimate``, ``refine``) and writes its declared
outputs; the rule scripts are shims over these.

The estimators see only what images give: the sparse pycolmap model's
points and cameras (``cloud`` turns them into an oriented cloud with
visibility and brightness). The shape model enters only as registration's
reference. Nothing here reads the truth, and this module imports nothing
that can (``tests/test_architecture.py``): the scoring, where registration
puts the cloud on the body and each point is matched to its closest facet,
whose normal, albedo and k are the truth, is :mod:`.table2_scoring`. The
light direction needs no registration: it lives in the camera frame.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from asteroid_photometry import estimation
from asteroid_photometry.core import files
from asteroid_photometry.core.failures import (
    check_npz,
    BadInput,
    check_status,
    DataFailure,
    OK,
    record,
    write_failed_npz,
    write_status_json,
)
from asteroid_photometry.estimation.fisher import cramer_rao_bounds
from asteroid_photometry.estimation.registry import run_estimator
from asteroid_photometry.evaluation import quality
from asteroid_photometry.from_images import cloud as cloud_lib, mesh_light, reconstruct, refine, register
from asteroid_photometry.from_images.purity import PurityTest
from asteroid_photometry.world.cameras import Intrinsics
from asteroid_photometry.world.degrade import FWHM_PER_SIGMA, psf_kernel
from asteroid_photometry.world.images import mission_navigation, read_mission, read_mission_file
from asteroid_photometry.world import observe
from asteroid_photometry.world.noise import sensor_from_config
from asteroid_photometry.world.shape import load_shape_npz, ROTATION_PERIOD_H

log = logging.getLogger(__name__)



MAX_MAPPER_SEEDS = 4
#: Fewer cloud points seen often enough than this is no model of the body (nor enough to register).
MIN_CLOUD_POINTS = 30
STATUS_FILE = "status.json"

#: The reconstruction keys (config key ``reconstruction``) each Table 2 stage reads, and no other: the rules pass
#: each stage only its own (:func:`stage_settings`), so a key read here but not declared fails loudly.
STAGE_KEYS = {
    "match_features": ("sift_peak_threshold", "guided_matching", "match_max_ratio", "match_max_turn_deg"),
    "reconstruct": (
        "intrinsics", "tie_point_sigma_px", "sift_peak_threshold", "guided_matching", "match_max_ratio", "match_max_turn_deg", "min_pose_inliers",
        "min_pose_inlier_ratio", "min_track",
    ),
    "register": ("min_track",),
    "cloud": ("min_observations_per_point", "min_cos_emission", "purity_tolerance"),
    "refine": (
        "min_observations_per_point", "min_cos_emission", "purity_tolerance", "refine_candidates", "refine_max_offset_px",
        "refine_offset_steps", "refine_purity_tolerance", "refine_max_residual",
    ),
}


def stage_settings(reconstruction: dict, stage: str) -> dict:
    """The keys of the config's ``reconstruction`` entry that ``stage`` reads (:data:`STAGE_KEYS`)."""
    return {key: reconstruction[key] for key in STAGE_KEYS[stage]}


def feature_options(settings: dict) -> reconstruct.FeatureOptions:
    """SIFT, matching and the mapper's registration thresholds from the config's ``reconstruction`` keys
    (those of ``match_features``; the mapper's where ``settings`` has them)."""
    mapper = {key: settings[key] for key in ("min_pose_inliers", "min_pose_inlier_ratio") if key in settings}
    return reconstruct.FeatureOptions(
        peak_threshold=settings["sift_peak_threshold"], guided_matching=settings["guided_matching"], max_ratio=settings["match_max_ratio"],
        max_turn_deg=settings["match_max_turn_deg"], **mapper,
    )


def rotation_phase_deg(mission: dict) -> np.ndarray:
    """Each image's rotation phase (degrees) from its time in the mission set and the body's rotation period (``ROTATION_PERIOD_H``)."""
    times_s = np.array([entry["time_s"] for entry in mission["images"]], dtype=float)
    return 360.0 * times_s / (ROTATION_PERIOD_H * 3600.0)


def outward_fraction(recon: reconstruct.SparseReconstruction, min_track: int = 3) -> float:
    """Fraction of the cloud's camera-facing normals that point away from its centroid.

    About 1 for a sound model of a (nearly) star-shaped body; near 0 for the
    depth-reversed twin that narrow-field structure from motion of a turning
    body can land in (the cameras then come out turned by 180 degrees and the
    surface is seen from inside).
    """
    oriented = oriented_cloud_of(recon, min_track)
    outward = np.einsum("ij,ij->i", oriented.normals, oriented.points - oriented.points.mean(axis=0)) > 0
    return float(outward.mean())


def ring_order(recon: reconstruct.SparseReconstruction, phase_deg) -> reconstruct.RingOrder:
    """How the model's cameras go round their ring against the image order: ``reconstruct.ring_order`` of its registered
    cameras' centres and those images' rotation phases (``phase_deg``, set order, from the image times).

    A sound model keeps the order, each camera near its place; a mapper that
    closed the ring wrongly (joined it through false matches, or bent a run of
    images onto the wrong side) leaves cameras out of order and many turns
    between images from their place, while its points may still reproject
    well. Reads the image times only: no prior, no truth.
    """
    indices, centres = _registered_centres(recon)
    return reconstruct.ring_order(centres, np.asarray(phase_deg, dtype=float)[indices])


def ring_outliers(recon: reconstruct.SparseReconstruction, phase_deg) -> np.ndarray | None:
    """The set indices of the cameras to take out of the model so that the rest keep the image order round their ring
    (``reconstruct.ring_outliers``, at most ``reconstruct.MAX_RING_OUTLIER_SHARE`` of the registered cameras); empty for
    a sound model, ``None`` where that share is not enough. Reads the image times only."""
    indices, centres = _registered_centres(recon)
    rows = reconstruct.ring_outliers(
        centres, np.asarray(phase_deg, dtype=float)[indices], int(reconstruct.MAX_RING_OUTLIER_SHARE * len(indices) + 1e-9),
    )
    return None if rows is None else indices[rows]


def _registered_centres(recon: reconstruct.SparseReconstruction) -> tuple[np.ndarray, np.ndarray]:
    """The registered images' set indices (ascending) and their camera centres (n, 3), in the model's frame."""
    centres = recon.camera_centres()
    indices = np.array(sorted(centres), dtype=int)
    return indices, np.array([centres[index] for index in indices]).reshape(-1, 3)


def oriented_cloud_of(recon: reconstruct.SparseReconstruction, min_track: int) -> cloud_lib.OrientedCloud:
    """The reconstruction's oriented cloud (``cloud.oriented_cloud``); :class:`DataFailure` if too few points are seen often enough."""
    _, xyz = recon.points3d()
    tracks = recon.tracks()
    n_tracked = int(np.count_nonzero(np.bincount(tracks["point"], minlength=len(xyz)) >= min_track))
    if n_tracked < MIN_CLOUD_POINTS:
        raise DataFailure(
            f"the model of {recon.report.n_images_registered} images has {n_tracked} points seen in at least {min_track} images "
            f"(at least {MIN_CLOUD_POINTS} needed)"
        )
    return cloud_lib.oriented_cloud(xyz, tracks["point"], tracks["image"], recon.camera_centres(), min_track=min_track)


def read_reconstruction(reconstruction_dir) -> reconstruct.SparseReconstruction:
    """The output of ``reconstruct_stage``; raises its recorded :class:`DataFailure` if it failed."""
    status_path = Path(reconstruction_dir) / STATUS_FILE
    if status_path.exists():
        check_status(json.loads(status_path.read_text()), status_path)
    return reconstruct.SparseReconstruction.read(reconstruction_dir)


def match_features_stage(mission_dir, out_dir, threads: int, settings: dict) -> None:
    """The 8-bit images, SIFT features and verified matches of one mission set (``reconstruct.match_images``), in ``out_dir``.

    What both reconstructions of a set (priors on and off) start from: no
    navigation prior enters here, and the two-view verification's RANSAC is
    seeded with ``reconstruct.MATCHING_SEED``. ``status.json`` in
    ``out_dir`` says ``ok``, or ``failed`` with the reason (a blank set, a
    failed mission set), which ``reconstruct_stage`` passes on.
    """
    out_dir = Path(out_dir)
    try:
        _match_features(mission_dir, out_dir, threads, settings)
    except DataFailure as failure:
        part = files.partial_directory(out_dir)
        write_status_json(part / STATUS_FILE, record("match_features", failure))
        files.move_into_place(part, out_dir)


def _match_features(mission_dir, out_dir: Path, threads: int, settings: dict) -> None:
    mission, images = read_mission(mission_dir)  # checked before any work
    part = files.partial_directory(out_dir)  # renamed to out_dir when complete
    reconstruct.match_images(
        images, Intrinsics(**mission["intrinsics"]), part, features=feature_options(settings), phase_deg=rotation_phase_deg(mission),
        num_threads=threads, seed=reconstruct.MATCHING_SEED,
    )
    write_status_json(part / STATUS_FILE)
    files.move_into_place(part, out_dir)


def reconstruct_stage(mission_dir, features_dir, out_dir, use_priors: bool, settings: dict) -> None:
    """Sparse reconstruction of one mission set from its matched features (``match_features_stage``), with or without its navigation priors.

    ``features_dir`` is only read (``reconstruct.map_matches`` copies its
    database); the mission set gives the navigation priors. A model whose
    surface faces inwards (``outward_fraction`` below 0.5) is the
    depth-reversed twin, not the body, and one whose cameras do not keep the
    image order round their ring (``ring_order``: a camera out of order, or
    ``reconstruct.RING_ORDER_TOLERANCE_STEPS`` or more from its place) was closed wrongly: either
    way the mapper is run again with the next seed, up to
    ``MAX_MAPPER_SEEDS`` times, and the attempts are logged and recorded in
    the report's settings. The matches are the same on
    every attempt (seeded once, by ``match_features_stage``): only the
    mapper's seed changes (the mapper's RANSACs, its choices and the final
    adjustment's). Where no seed gives a sound model, the outward-facing
    model that keeps the order with fewest cameras taken out, at most
    ``reconstruct.MAX_RING_OUTLIER_SHARE`` of them, is kept without them,
    adjusted again (``_without_ring_outliers``; the report's settings name
    them in ``images_taken_out``). ``status.json`` in ``out_dir`` says ``ok``, or
    ``failed`` with the reason: too few images registered
    (``reconstruct.MIN_REGISTERED_IMAGES``), fewer than ``MIN_CLOUD_POINTS``
    points, no sound model (above) on any seed, or the features stage's
    own failure (a blank set), passed on.
    """
    out_dir = Path(out_dir)
    try:
        _reconstruct(mission_dir, features_dir, out_dir, use_priors, settings)
    except DataFailure as failure:
        part = files.partial_directory(out_dir)
        write_status_json(part / STATUS_FILE, record("reconstruct", failure))
        files.move_into_place(part, out_dir)


def _reconstruct(mission_dir, features_dir, out_dir, use_priors: bool, settings: dict) -> None:
    mission = read_mission_file(mission_dir)  # checked before any work
    prior_positions, prior_sigma_m = mission_navigation(mission)
    if use_priors and prior_positions is None:
        raise BadInput(
            f"{mission_dir}: a reconstruction with priors asked for, but the mission set has no navigation priors "
            f"(its imaging condition {mission.get('imaging')!r} has prior_sigma_m 0)"
        )
    status_path = Path(features_dir) / STATUS_FILE
    check_status(json.loads(status_path.read_text()), status_path)  # the features stage's failure, passed on
    phase_deg = rotation_phase_deg(mission)
    attempts, facing_out = [], []
    part = files.partial_directory(out_dir)  # renamed to out_dir when complete
    for seed in range(MAX_MAPPER_SEEDS):
        result = reconstruct.map_matches(
            features_dir, part / "work", prior_positions=prior_positions if use_priors else None,
            intrinsics_mode=settings["intrinsics"], camera_position_sigma_m=prior_sigma_m if use_priors else 1.0,
            tie_point_sigma_px=settings["tie_point_sigma_px"], seed=seed,
            features=feature_options(settings),
        )
        n_registered = result.report.n_images_registered
        fraction = outward_fraction(result, settings["min_track"])
        ring = ring_order(result, phase_deg)
        attempts.append({
            "seed": seed, "outward_fraction": fraction, "ring_order_error_steps": ring.error_steps, "ring_order_kept": ring.order_kept,
            "n_images_registered": n_registered,
        })
        if fraction >= 0.5 and ring.sound:
            break
        if fraction >= 0.5:
            facing_out.append((seed, result))
        if fraction < 0.5:
            log.warning("mapper seed %d gave a depth-reversed model (%.0f %% of normals face outwards); trying the next seed", seed, 100 * fraction)
        else:
            log.warning(
                "mapper seed %d gave cameras %s round their ring (a camera %.2f turns between images from its place, under %g "
                "needed): a ring closed wrongly; trying the next seed", seed, "in the image order" if ring.order_kept else "out of the image order",
                ring.error_steps, reconstruct.RING_ORDER_TOLERANCE_STEPS,
            )
    else:
        result = _without_ring_outliers(facing_out, phase_deg, settings["min_track"])
        if result is None:
            raise DataFailure(
                f"no sound model on any of {MAX_MAPPER_SEEDS} mapper seeds: outward fractions (0.5 needed; below, the model is "
                "depth-reversed, seen from inside) "
                + ", ".join(f"{attempt['outward_fraction']:.2f}" for attempt in attempts)
                + f"; cameras' largest distance from their place in the image order round the ring, in turns between images "
                f"(under {reconstruct.RING_ORDER_TOLERANCE_STEPS:g} needed) "
                + ", ".join(f"{attempt['ring_order_error_steps']:.2f}" for attempt in attempts)
                + "; the image order kept (needed) "
                + ", ".join("yes" if attempt["ring_order_kept"] else "no" for attempt in attempts)
                + f"; nor with at most {reconstruct.MAX_RING_OUTLIER_SHARE:.0%} of a model's cameras taken out"
            )
    result.report.settings["mapper_attempts"] = attempts
    result.write(part)
    write_status_json(part / STATUS_FILE)
    files.move_into_place(part, out_dir)
    log.info("reconstruction: %s", json.dumps(result.report.to_dict()))


def _without_ring_outliers(models, phase_deg, min_track: int) -> reconstruct.SparseReconstruction | None:
    """Of the mapper's models ``(seed, model)`` that face outwards but failed the ring check, the one that needs fewest
    cameras taken out to keep the image order (``ring_outliers``; the earliest seed of equals), with those cameras taken
    out and the rest adjusted again; ``None`` where none will do, or where the adjusted model faces inwards or leaves
    the order after all. Logged as a warning: the images taken out get no observations from this model."""
    chosen = None
    for seed, model in models:
        outliers = ring_outliers(model, phase_deg)
        if outliers is not None and (chosen is None or len(outliers) < len(chosen[2])):
            chosen = (seed, model, outliers)
    if chosen is None:
        return None
    seed, model, outliers = chosen
    kept = model.without_images(outliers, seed=seed)
    fraction, ring = outward_fraction(kept, min_track), ring_order(kept, phase_deg)
    log.warning(
        "no mapper seed gave a sound ring; seed %d's model keeps the image order with images %s taken out (%d of %d "
        "registered): adjusted again, the rest %.2f turns between images from their places at most, in order: %s, "
        "outward fraction %.2f", seed, outliers.tolist(), len(outliers), model.report.n_images_registered, ring.error_steps,
        "yes" if ring.order_kept else "no", fraction,
    )
    if fraction < 0.5 or not ring.sound:
        return None
    kept.report.settings["ring_after_images_taken_out"] = {
        "seed": int(seed), "outward_fraction": fraction, "ring_order_error_steps": ring.error_steps, "ring_order_kept": ring.order_kept,
    }
    return kept


def register_stage(reconstruction_dir, shape_npz, settings: dict, out_npz, out_json) -> None:
    """The oriented cloud of a reconstruction, registered to the shape model and scored.

    A failed registration (``RegistrationResult.failure_reason``), or a failed
    reconstruction passed on, is written as ``status: failed`` with the
    reason: its transform is wrong, and nothing is scored through it.
    """
    try:
        recon = read_reconstruction(reconstruction_dir)
        shape = load_shape_npz(shape_npz)
        oriented = oriented_cloud_of(recon, settings["min_track"])
        in_body_frame = recon.report.world_frame == "body"
        result = register.register_to_shape(oriented.points, oriented.normals, shape["vertices_m"], shape["faces"], estimate_scale=not in_body_frame)
    except DataFailure as failure:
        reason = record("register_cloud", failure)
        write_failed_npz(out_npz, reason)
        write_status_json(out_json, reason, registration_ok=False)
        return
    summary = {
        "registration_ok": bool(result.success),
        "registration_seconds": float(result.seconds_global + result.seconds_icp),
        "registration_rms_rel": float(result.rms_distance_rel),
        "registration_scale": float(result.scale),
        "registration_fitness": float(result.fitness),
        "registration_ambiguity": float(result.ambiguity),
        "n_cloud_points": int(len(oriented.points)),
    }
    if not result.success:
        reason = record("register_cloud", DataFailure(result.failure_reason))
        write_failed_npz(out_npz, reason)
        write_status_json(out_json, reason, **summary)
        return
    scores = quality.reconstruction_quality(oriented.points, oriented.normals, shape["vertices_m"], shape["faces"], transform=result.transform)
    files.savez(out_npz, points=oriented.points, normals=oriented.normals, track_length=oriented.track_length, transform=result.transform)
    summary = {
        "status": OK,
        **summary,
        "accuracy_rel_median": scores.accuracy_median_rel,
        "accuracy_m_median": scores.accuracy_median_m,
        "completeness": scores.completeness,
        "normal_err_deg_median": scores.normal_error_median_deg,
    }
    files.write_json(out_json, summary)
    log.info("registration and quality: %s", summary)


def refine_stage(registration_npz, reconstruction_dir, mission_dir, settings: dict, out_npz) -> None:
    """The photometric refinement of one reconstruction (``refine.refine_by_pure_samples``), from images and cloud alone.

    The light it holds fixed, and the albedo and k it starts from, are the
    paper's estimator's on the cloud's bilinear samples; at the end it fits
    the light again to the pure samples, with one k for the body
    (``PureSampleCloud.refined_light_dir_cam``). Only the cloud's
    points and normals are read from the registration file: its transform
    to the shape model is not used; but a set whose registration failed
    cannot be scored, and is passed on (``status: failed``) unrefined.
    """
    try:
        pure = _refine(registration_npz, reconstruction_dir, mission_dir, settings)
    except DataFailure as failure:
        write_failed_npz(out_npz, record("refine_cloud", failure))
        return
    pure.save(out_npz)
    log.info("refinement: %d of %d candidates kept, %d pure samples, median offset %.2f px", len(pure.points), pure.n_candidates, pure.observations.n_obs, float(np.median(np.abs(pure.offset_px))))


def read_registered_cloud(registration_npz) -> cloud_lib.OrientedCloud:
    """The oriented cloud rule ``register_cloud`` wrote (its own frame); raises the recorded failure of a stage before."""
    with np.load(registration_npz) as data:
        check_npz(data, registration_npz)
        return cloud_lib.OrientedCloud(data["points"], data["normals"], data["track_length"])


def read_refined_cloud(refined_npz) -> refine.PureSampleCloud:
    """The refined cloud rule ``refine_cloud`` (or ``final_cloud``) wrote; raises the recorded failure of a stage before."""
    with np.load(refined_npz) as data:
        check_npz(data, refined_npz)
    return refine.PureSampleCloud.load(refined_npz)


def _refine(registration_npz, reconstruction_dir, mission_dir, settings: dict) -> refine.PureSampleCloud:
    oriented = read_registered_cloud(registration_npz)
    recon = read_reconstruction(reconstruction_dir)
    mission, images = read_mission(mission_dir)
    # Images with a sensor model: the statistical purity test of that sensor; noise-free ones: the relative tolerance.
    purity_test = PurityTest(sensor_from_config(mission["sensor"])) if mission.get("sensor") else settings["refine_purity_tolerance"]
    surface = cloud_lib.poisson_surface(oriented)
    gain_sigma = float(mission.get("gain_sigma") or 0.0)
    start = _refinement_start(oriented, surface, recon, images, settings)
    # Under a sensor with per-image gains, in the camera ring's plane (where the light step fits the gains): two
    # passes (refine.CALIBRATION_PASSES). The first, on a share of the candidates, only finds the gains: its residual
    # test allows their scatter. The second runs on the images divided by them, its residual test the sensor's alone,
    # so it keeps the points one facet explains rather than those whose fit absorbed the gains (docs/table2.md, section 6).
    two_passes = refine.CALIBRATION_PASSES >= 2 and gain_sigma > 0 and callable(purity_test) and start[3] is not None
    if not two_passes:
        pure = _refine_pass(surface, recon, images, purity_test, settings, start, gain_sigma, residual_gain_sigma=0.0)
        # With the normals free to tilt, each pass's normals follow the light they were fitted under and its light step
        # takes part of that light's elevation error off: again from the step's light until it settles
        # (refine.FREE_TILT_PASSES, refine.FREE_TILT_SETTLED_DEG; docs/table2.md, section 0).
        if start[3] is None:
            pure = refine.refine_until_settled(
                pure, lambda last: _refine_pass(surface, recon, images, purity_test, settings, (last.refined_light_dir_cam, start[1], last.refined_minnaert_k, None), gain_sigma, residual_gain_sigma=0.0),
                refine.FREE_TILT_PASSES, refine.FREE_TILT_SETTLED_DEG,
            )
        return pure
    share = max(1000, round(refine.FIRST_PASS_CANDIDATE_SHARE * settings["refine_candidates"]))
    first = _refine_pass(surface, recon, images, purity_test, dict(settings, refine_candidates=share), start, gain_sigma, residual_gain_sigma=gain_sigma)
    corrected = [image / gain for image, gain in zip(images, first.image_gains)]
    # The cloud's estimate taken again on the corrected images; the axis the normals turn about stays the first
    # pass's: the second pass exists to refine under the first's gains, which only its light step in the ring's
    # plane fits (a restart whose light leaves the plane would drop that step and its gains).
    restart = (*_cloud_estimate(oriented, surface, recon, corrected, settings), start[3])
    second = _refine_pass(surface, recon, corrected, purity_test, settings, restart, gain_sigma, residual_gain_sigma=0.0)
    log.info(
        "second pass on the images over the first pass's gains (%.4f to %.4f): %d points kept (first pass %d of %d candidates)",
        float(first.image_gains.min()), float(first.image_gains.max()), len(second.points), len(first.points), first.n_candidates,
    )
    return replace(second, image_gains=first.image_gains * second.image_gains)


# ---------------------------------------------------------------- mesh_light: the light from a shape from shading on one mesh

#: The mesh fit's light replaces the refinement's only where the refinement's k for the body is at least this. Near
#: k = 0.5 the brightness hardly depends on the surface's slope, and the heights and the light trade against each
#: other: on the tuning grids (config/tuning.yaml, config/tuning_mid.yaml; none of the paper's sets) the fit took 2 of
#: 5 k-0.55 rows out of Table 2's bounds and brought every k-0.75 and k-0.95 row within them (docs/table2.md, section 13).
MESH_LIGHT_MIN_K = 0.65


#: The octree depth of the cloud's Poisson surface the mesh fit starts from (the refinement samples one of depth 7,
#: ``cloud.poisson_surface``'s default). A finer surface follows the cloud's curvature more closely where the
#: coarser one flattens it (its normals at high latitudes 1.5 to 3 degrees towards the equator on tuning_mid's rows);
#: at light 0 the light leans out of the camera ring's plane with that error. Chosen on config/tuning_mid.yaml's
#: `amica` rows (none of the paper's sets): the worst light 0.885 degrees against 0.972, the four light-0, k-0.75
#: rows 0.09 to 0.18 degrees nearer (docs/amica_record.md, "Where the mesh fit's light error at light 0 comes from").
MESH_LIGHT_POISSON_DEPTH = 8


def mesh_light_skipped(pure: refine.PureSampleCloud) -> str | None:
    """Why the mesh fit is not run on a refined cloud (``None``: it is): a k below :data:`MESH_LIGHT_MIN_K`."""
    if not pure.refined_minnaert_k >= MESH_LIGHT_MIN_K:
        return f"the refinement's k for the body ({pure.refined_minnaert_k:.3f}) is below {MESH_LIGHT_MIN_K}: the shading says too little about the slopes"
    return None


#: The mission's stated PSF enters the mesh fit's model as its Gaussian core cut this many standard deviations out
#: (2 pixels for a FWHM of 1.5): beyond that the core holds under 0.3 % of the light.
MESH_LIGHT_PSF_SIGMAS = 3.0


def mesh_light_psf(mission: dict) -> np.ndarray | None:
    """The kernel the mesh fit blurs its model by: the camera's stated PSF core (the mission's ``psf_fwhm_px``, a
    calibration a mission has) out to :data:`MESH_LIGHT_PSF_SIGMAS`; ``None`` where the mission states no blur."""
    fwhm = float(mission.get("psf_fwhm_px") or 0.0)
    if fwhm <= 0.0:
        return None
    return psf_kernel(fwhm, radius_px=max(1, int(np.ceil(MESH_LIGHT_PSF_SIGMAS * fwhm / FWHM_PER_SIGMA))))


def fit_mesh_light_on(pure: refine.PureSampleCloud, oriented: cloud_lib.OrientedCloud, recon, mission: dict, images) -> mesh_light.MeshLight:
    """The mesh fit as rule ``mesh_light`` runs it: on the cloud's Poisson surface (:data:`MESH_LIGHT_POISSON_DEPTH`),
    the images over the refinement's gains, from the refinement's light and k, under the mission's sensor model,
    stated calibration scatter and stated PSF (``mesh_light_psf``). ``ValueError`` where the surface shows too few
    pixels."""
    gains = pure.image_gains if pure.image_gains is not None else np.ones(len(images))
    vertices, triangles = cloud_lib.poisson_surface(oriented, depth=MESH_LIGHT_POISSON_DEPTH)
    return mesh_light.fit_mesh_light(
        vertices, triangles, recon.camera_centres(), recon.body_to_camera(), recon.intrinsics(), [image / gain for image, gain in zip(images, gains)],
        # Noise-free images: no sensor variance, the residuals over the fit's relative floor alone.
        PurityTest(sensor_from_config(mission["sensor"])).sample_variance if mission.get("sensor") else None,
        pure.refined_light_dir_cam, pure.refined_minnaert_k,
        float(mission.get("gain_sigma") or 0.0), psf=mesh_light_psf(mission),
    )


def mesh_light_stage(registration_npz, reconstruction_dir, mission_dir, refined_npz, out_npz) -> None:
    """The light of a shape from shading on the cloud's surface (``mesh_light.fit_mesh_light``), from the refinement's.

    Writes ``applied`` (whether the final fit is to hold this light instead of
    the refinement's) and, when applied, the fit's light (camera frame), k,
    log gains and size; else ``reason``. A set whose refinement failed passes
    that on; a fit that fails leaves the refinement's light, with the reason.
    No truth is read.
    """
    tick = time.perf_counter()
    try:
        pure = read_refined_cloud(refined_npz)
        mission, images = read_mission(mission_dir)
        reason = mesh_light_skipped(pure)
        if reason is None:
            oriented = read_registered_cloud(registration_npz)
            try:
                fit = fit_mesh_light_on(pure, oriented, read_reconstruction(reconstruction_dir), mission, images)
            except ValueError as error:
                reason = f"the mesh fit failed ({error}): the refinement's light is kept"
    except DataFailure as failure:
        write_failed_npz(out_npz, record("mesh_light", failure))
        return
    if reason is not None:
        log.info("mesh light not applied: %s", reason)
        files.savez(out_npz, status=np.str_(OK), applied=False, reason=np.str_(reason))
        return
    turn = estimation.angle_between_deg(fit.light_dir_cam, pure.refined_light_dir_cam)
    log.info("mesh light: %.3f deg from the refinement's, k %.4f (refinement %.4f), %d samples, %d steps, %.0f s", turn, fit.minnaert_k, pure.refined_minnaert_k, fit.n_samples, fit.n_steps, time.perf_counter() - tick)
    files.savez(
        out_npz, status=np.str_(OK), applied=True, reason=np.str_(""), light_dir_cam=fit.light_dir_cam, minnaert_k=fit.minnaert_k,
        log_gains=fit.log_gains, image_indices=fit.image_indices, n_samples=fit.n_samples, n_vertices=fit.n_vertices, n_steps=fit.n_steps, cost=fit.cost,
        turn_from_refinement_deg=turn, seconds=time.perf_counter() - tick,
    )


def mesh_light_of(path, n_images: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The light and the per-image gains :func:`mesh_light_stage` wrote to ``path`` where they are to be applied, else
    ``None``; raises its recorded failure. The gains, by image index (``n_images`` of them), are the mesh fit's on the
    images over the refinement's gains, their geometric mean over the images the fit used put at one (the albedo keeps
    the scale); an image the fit did not use gets one."""
    with np.load(path) as data:
        check_npz(data, path)
        if not bool(data["applied"]):
            return None
        log_gains, indices = np.asarray(data["log_gains"], float), np.asarray(data["image_indices"], int)
        gains = np.ones(n_images)
        gains[indices] = np.exp(log_gains - log_gains.mean())
        return np.asarray(data["light_dir_cam"], float), gains


def under_mesh_light(stage: CloudStage, held: tuple[np.ndarray, np.ndarray] | None) -> CloudStage:
    """``stage`` with the mesh fit's light and gains (:func:`mesh_light_of`; ``None``: unchanged) in place of the
    refinement's: the final fit holds that light, on the samples over the mesh fit's gains. Fitted to every pixel,
    they take off the calibration error the refinement's left (all of it where the normals tilt freely and the
    refinement fits none; docs/table2.md, section 13)."""
    if held is None:
        return stage
    light, gains = held
    return replace(stage, pure=replace(stage.pure.over_gains(gains), refined_light_dir_cam=light))


# ---------------------------------------------------------------- final_cloud: the refined cloud the final fit reads


def final_cloud_stage(registration_npz, reconstruction_dir, mission_dir, refined_npz, mesh_light_npz, settings: dict, out_npz) -> None:
    """The refined cloud the final per-point fit and its scoring read (rule ``final_cloud``).

    On noise-free images where the mesh fit's light is held, the refined
    points' normals fitted again under that light (:func:`refit_under_light`):
    fitted under the refinement's light and held under another, they leave k
    to take up the difference (light 35 on the tuning grid: k 0.03 low;
    docs/table2.md, section 15). Elsewhere the refinement's cloud unchanged:
    under a sensor the same refit raised the albedo on the tuning sets. No
    truth is read. Where the refinement's cloud stands, the file says so
    (``refitted`` false, ``reason``) rather than copying it
    (:func:`final_cloud_path`).
    """
    try:
        pure = read_refined_cloud(refined_npz)
        mission, images = read_mission(mission_dir)
        held = mesh_light_of(mesh_light_npz, len(images))
        if held is None or mission.get("sensor"):
            reason = "the mesh fit's light is not held" if held is None else "images with a sensor model: the refit raised the albedo on the tuning sets"
            log.info("the refinement's cloud is the final one: %s", reason)
            files.savez(out_npz, status=np.str_(OK), refitted=False, reason=np.str_(reason))
            return
        refitted = refit_under_light(pure, read_registered_cloud(registration_npz), read_reconstruction(reconstruction_dir), images, held, settings)
    except DataFailure as failure:
        write_failed_npz(out_npz, record("final_cloud", failure))
        return
    refitted.save(out_npz)
    log.info("normals refitted under the mesh fit's light: %d points, %d pure samples (the refinement's: %d, %d)", len(refitted.points), refitted.observations.n_obs, len(pure.points), pure.observations.n_obs)


def final_cloud_path(refined_npz, final_cloud_npz):
    """The refined cloud the final fit reads: ``final_cloud_npz`` (:func:`final_cloud_stage`) where it holds a refitted
    cloud, else ``refined_npz``; ``final_cloud_npz`` None: ``refined_npz``. Raises its recorded failure."""
    if final_cloud_npz is None:
        return refined_npz
    with np.load(final_cloud_npz) as data:
        check_npz(data, final_cloud_npz)
        return final_cloud_npz if "points" in data.files else refined_npz


def refit_under_light(pure: refine.PureSampleCloud, oriented, recon, images, held: tuple[np.ndarray, np.ndarray], settings: dict) -> refine.PureSampleCloud:
    """One pass of the pure-sample refinement (noise-free images: the relative purity tolerance) with the light held at
    ``held``'s (:func:`mesh_light_of`), on the images over both gains. The cloud keeps the refinement's light, k and
    gains as its own, its samples over the refinement's gains only (the final fit divides the mesh fit's out again)."""
    light, mesh_gains = held
    gains = (pure.image_gains if pure.image_gains is not None else np.ones(len(images))) * mesh_gains
    poses = recon.body_to_camera()
    axis = None if pure.normals_tilt_freely else refine.turn_axis(poses, oriented.points.mean(axis=0), light)[0]
    # Each point's one-facet fit starts from the body's typical albedo under that light (the final fit's median).
    over = pure.over_gains(mesh_gains)
    lit = lit_samples(over.observations, light, FINAL_MIN_COS_INCIDENCE, settings["min_observations_per_point"])
    start_albedo = float(np.nanmedian(run_estimator(lit, "koizumi_lm", light_init=light, hold_light=True).albedo))
    refitted = _pure_samples(
        cloud_lib.poisson_surface(oriented), recon, [image / gain for image, gain in zip(images, gains)],
        (light, start_albedo, float(pure.refined_minnaert_k), axis), settings["refine_purity_tolerance"], settings,
    )
    if refitted.observations.n_obs < 10 * settings["min_observations_per_point"]:
        raise DataFailure(f"the refit under the mesh fit's light kept {len(refitted.points)} of {refitted.n_candidates} candidate points ({refitted.observations.n_obs} pure samples); too few to fit")
    # Its samples back over the refinement's gains alone: the final fit divides the mesh fit's out (under_mesh_light).
    return replace(
        refitted.over_gains(1.0 / mesh_gains), light_dir_cam=light, refined_light_dir_cam=pure.refined_light_dir_cam,
        refined_minnaert_k=pure.refined_minnaert_k, image_gains=pure.image_gains, normals_tilt_freely=pure.normals_tilt_freely,
    )


def _cloud_estimate(oriented, surface, recon, images, settings: dict):
    """The paper's estimate on the cloud's samples of ``images``: (light, median albedo, median k)."""
    obs, _ = cloud_observations_of(oriented, recon, images, settings, surface)
    require_cloud_observations(obs, settings, "the cloud")
    start = run_estimator(obs, "koizumi_lm")
    fitted = np.isfinite(start.albedo) & np.isfinite(start.minnaert_k)
    return start.light_dir_cam, float(np.median(start.albedo[fitted])), float(np.median(start.minnaert_k[fitted]))


def _refinement_start(oriented, surface, recon, images, settings: dict):
    """Where the refinement starts: :func:`_cloud_estimate` and the axis it decides, as (light, albedo, k, spin axis
    or None where the normals tilt freely)."""
    light_dir_cam, albedo, minnaert_k = _cloud_estimate(oriented, surface, recon, images, settings)
    axis, view_deg, light_deg = refine.turn_axis(recon.body_to_camera(), oriented.points.mean(axis=0), light_dir_cam)
    log.info(
        "views %.1f deg and light %.1f deg out of the camera ring's plane: normals %s", view_deg, light_deg,
        "turn about the spin axis" if axis is not None else f"tilt freely (above {refine.IN_PLANE_LIMIT_DEG:g} deg)",
    )
    return light_dir_cam, albedo, minnaert_k, axis


def _pure_samples(surface, recon, images, start, purity_test, settings: dict, residual_gain_sigma: float = 0.0) -> refine.PureSampleCloud:
    """``refine.refine_by_pure_samples`` from ``start`` (light, albedo, k, axis) with the stage's settings."""
    light_dir_cam, albedo, minnaert_k, axis = start
    return refine.refine_by_pure_samples(
        surface, recon.body_to_camera(), recon.intrinsics(), images, light_dir_cam, albedo, minnaert_k,
        n_candidates=settings["refine_candidates"], max_offset_px=settings["refine_max_offset_px"], offset_steps=settings["refine_offset_steps"],
        purity_tolerance=purity_test, max_residual=settings["refine_max_residual"],
        min_observations=settings["min_observations_per_point"], min_cos_emission=settings["min_cos_emission"],
        axis=axis, gain_sigma=residual_gain_sigma,
    )


def _refine_pass(surface, recon, images, purity_test, settings: dict, start, gain_sigma: float, residual_gain_sigma: float) -> refine.PureSampleCloud:
    """One refinement on ``images`` from ``start`` (:func:`_refinement_start`): the pure-sample refinement (its residual
    test allowing ``residual_gain_sigma`` of calibration scatter) and, under a sensor in the ring's plane, the light
    step with a gain per image (prior ``gain_sigma``)."""
    axis = start[3]
    poses = recon.body_to_camera()
    pure = _pure_samples(surface, recon, images, start, purity_test, settings, residual_gain_sigma)
    if pure.observations.n_obs < 10 * settings["min_observations_per_point"] or not np.all(np.isfinite(pure.refined_light_dir_cam)):
        raise DataFailure(
            f"the refinement kept {len(pure.points)} of {pure.n_candidates} candidate points "
            f"({pure.observations.n_obs} pure samples); too few to fit (more with a larger reconstruction.refine_candidates, "
            f"refine_purity_tolerance or refine_max_residual)"
        )
    if callable(purity_test) and axis is not None:
        # Under a sensor: the normals' common turn fixed by the surface, the light with each point's k held to the
        # body's and a gain per image (refine.anchored_light; docs/table2.md, section 7).
        try:
            pure = refine.anchored_light(
                pure, poses, axis, lambda brightness: np.sqrt(purity_test.sample_variance(brightness)) / brightness,
                gain_sigma=gain_sigma, n_images=len(images), min_observations=settings["min_observations_per_point"],
            )
        except ValueError as error:
            raise DataFailure(f"the light step under the sensor failed: {error}") from error
    return pure


def require_cloud_observations(obs, settings: dict, what: str) -> None:
    """:class:`DataFailure` unless ``obs`` has at least ten points' worth of observations (the fits' own minimum)."""
    if obs.n_obs < 10 * settings["min_observations_per_point"]:
        raise DataFailure(f"{what} gives only {obs.n_obs} usable observations of {int(np.count_nonzero(obs.observations_per_point))} points; nothing to fit")


def cloud_observations_of(oriented, recon, images, settings: dict, surface=None):
    """``cloud.cloud_observations`` of a reconstruction's cloud with the config's settings."""
    return cloud_lib.cloud_observations(
        oriented, recon.body_to_camera(), recon.intrinsics(), images, min_cos_emission=settings["min_cos_emission"],
        min_observations=settings["min_observations_per_point"], purity_tolerance=settings.get("purity_tolerance"), surface=surface,
    )


#: A cloud point whose fitted Minnaert k leaves this range (physical values
#: lie near 0.5 to 1.2) has no fit worth scoring: its normal or its samples
#: are far off, and one such point (k = 4.5, albedo 1e2 to 1e8 from a few
#: grazing samples) can carry a set's mean albedo error to any value. Such
#: points are left out, and counted in the log and in n_points.
PLAUSIBLE_K = (0.0, 3.0)


def plausible_points(result: estimation.FitResult) -> estimation.FitResult:
    """``result`` with the points of implausible k marked unfitted (NaN), for scoring."""
    low, high = PLAUSIBLE_K
    implausible = np.isfinite(result.minnaert_k) & ((result.minnaert_k < low) | (result.minnaert_k > high))
    if not implausible.any():
        return result
    log.warning("%s: %d of %d fitted points have k outside [%g, %g] and are left out", result.method, int(implausible.sum()), result.n_points_fitted, low, high)
    return replace(
        result, albedo=np.where(implausible, np.nan, result.albedo), minnaert_k=np.where(implausible, np.nan, result.minnaert_k),
        n_points_fitted=result.n_points_fitted - int(implausible.sum()),
    )


# ---------------------------------------------------------------- estimate_cloud: the estimators on the cloud (scored in .table2_scoring)


@dataclass(frozen=True)
class CloudStageInputs:
    """The files the estimates on a cloud come from, none of them truth: the outputs of ``register_stage``
    (``registration_npz``, ``registration_json``), ``reconstruct_stage`` (``reconstruction_dir``) and
    ``refine_stage`` (``refined_npz``), ``mesh_light_stage`` (``mesh_light_npz``, optional), ``final_cloud_stage``
    (``final_cloud_npz``, optional: where it refitted the cloud, the cloud read instead of ``refined_npz``), and the mission set (``mission_dir``)."""

    registration_npz: str | Path
    registration_json: str | Path
    reconstruction_dir: str | Path
    mission_dir: str | Path
    refined_npz: str | Path
    mesh_light_npz: str | Path | None = None
    final_cloud_npz: str | Path | None = None

    @classmethod
    def from_rule_input(cls, rule_input) -> CloudStageInputs:
        """The files named as rules ``estimate_cloud`` and ``score_cloud`` name their inputs (``snakemake.input``)."""
        return cls(
            rule_input.registration, rule_input.registration_summary, rule_input.model, rule_input.mission, rule_input.refined,
            getattr(rule_input, "mesh_light", None), getattr(rule_input, "final_cloud", None),
        )


@dataclass(frozen=True)
class CloudStage:
    """The inputs of :func:`estimate_cloud_stage` and of the scoring (``table2_scoring.score_cloud_stage``), read and checked.

    ``registration``: the registration's summary; ``report``: the
    reconstruction's; ``oriented``: the cloud in its own frame and
    ``transform`` from it to the body frame; ``mission`` and ``images``: the
    mission set; ``obs``: the cloud's samples of the images; ``pure``: the
    refined cloud and its pure samples.
    """

    registration: dict
    report: dict
    recon: reconstruct.SparseReconstruction
    oriented: cloud_lib.OrientedCloud
    transform: np.ndarray
    mission: dict
    images: object
    obs: estimation.Observations | None
    pure: refine.PureSampleCloud


def read_cloud_stage(inputs: CloudStageInputs, settings: dict, observations: bool = True) -> CloudStage:
    """The stage's inputs; raises the recorded :class:`DataFailure` of a stage before that failed, or one for too few observations.

    ``observations=False`` leaves the cloud's samples of the images out (``obs`` None): the scoring needs the
    cloud, the cameras and the images, not the estimator's samples, whose sampling costs seconds per job.
    """
    registration = json.loads(Path(inputs.registration_json).read_text())
    check_status(registration, inputs.registration_json)  # a failed registration's transform is wrong: nothing is scored through it
    # Refinement: samples moved to where the images show them pure, normals fitted to them (refine_stage).
    pure = read_refined_cloud(final_cloud_path(inputs.refined_npz, inputs.final_cloud_npz))
    recon = read_reconstruction(inputs.reconstruction_dir)
    with np.load(inputs.registration_npz) as data:
        check_npz(data, inputs.registration_npz)
        oriented = cloud_lib.OrientedCloud(data["points"], data["normals"], data["track_length"])
        transform = data["transform"]
    mission, images = read_mission(inputs.mission_dir)
    obs = None
    if observations:
        obs, _ = cloud_observations_of(oriented, recon, images, settings)
        require_cloud_observations(obs, settings, f"the reconstruction ({recon.report.n_images_registered} images, {len(oriented.points)} cloud points)")
    report = json.loads((Path(inputs.reconstruction_dir) / "report.json").read_text())
    return CloudStage(registration, report, recon, oriented, transform, mission, images, obs, pure)


@dataclass(frozen=True)
class CloudFits:
    """The estimator's fits, implausible points marked unfitted (:func:`plausible_points`): on the cloud
    (``before``) and on the refined cloud (``after``); ``joint``: after refinement, koizumi_lm's own joint fit
    with the light free (else ``after``); ``refit_seconds``: the wall time of the fits after refinement."""

    before: estimation.FitResult
    after: estimation.FitResult
    joint: estimation.FitResult
    refit_seconds: float


def estimate_before_refinement(stage: CloudStage, method: str, known_k: float) -> estimation.FitResult:
    """The estimator on the cloud's samples."""
    return plausible_points(run_estimator(stage.obs, method, known_k=known_k, robust=True))


#: The paper's per-point albedo and k under the refinement's light use the samples that light lights: a sample it
#: puts at grazing incidence or in shadow (cosine below this; Table 1's default incidence cut) makes its point's
#: albedo unbounded. The refinement chose its samples under the light it started from; where its own light moves
#: far from that (the `oblique` condition: 5 degrees) a few of them fall beyond the terminator.
FINAL_MIN_COS_INCIDENCE = 0.1


def lit_samples(observations: estimation.Observations, light_dir_cam, min_cos_incidence: float, min_observations: int) -> estimation.Observations:
    """The rows of ``observations`` that ``light_dir_cam`` lights at a cosine of at least ``min_cos_incidence``, of the
    points left with at least ``min_observations`` of them (the others lose all their rows); the points' numbering is kept."""
    return rows_of_points_kept_enough(observations, observations.cos_incidence(light_dir_cam) >= min_cos_incidence, min_observations)


def rows_of_points_kept_enough(observations: estimation.Observations, keep: np.ndarray, min_observations: int) -> estimation.Observations:
    """The rows ``keep`` marks, of the points it keeps at least ``min_observations`` times (the others lose all their
    rows); the points' numbering is kept."""
    return observations.rows(observe.enough_observations(observations.point_index, keep, observations.n_points, min_observations))


#: The final per-point fit leaves out the samples seen beyond 70 degrees of emission (cosine below this). The refinement
#: keeps samples down to its own ``min_cos_emission`` (0.2) to place and tilt the points, but near the limb a normal's
#: error of a degree or two moves the emission cosine by a large fraction and a pixel's footprint spans metres of
#: relief and the point spread function's tail: those samples pulled the per-point k low (about -0.01 under `amica`)
#: and the albedo high. Chosen on tuning sets only, none of the paper's: config/tuning_mid.yaml's 16 `amica` rows (mean
#: |k| 0.0073 -> 0.0048, every row nearer), config/tuning.yaml's 12 `amica` k-1.15 rows (0.0111 -> 0.0091) and
#: config/conditions_geometry.yaml's `oblique` rows (0.0070 -> 0.0042), `ideal` unchanged; 60, 65 and 75 degrees were
#: worse on the tuning grid (docs/table2.md, section 14).
FINAL_MIN_COS_EMISSION = 0.34


def seen_within_emission(observations: estimation.Observations, min_cos_emission: float, min_observations: int) -> estimation.Observations:
    """The rows of ``observations`` seen at an emission cosine of at least ``min_cos_emission``, of the points left with
    at least ``min_observations`` of them; the points' numbering is kept."""
    return rows_of_points_kept_enough(observations, observations.cos_emission >= min_cos_emission, min_observations)


#: Where the refinement's normals tilted freely (``PureSampleCloud.normals_tilt_freely``: the `oblique` condition), the
#: final fit keeps only the points its light lights at a mean incidence cosine of at least this (60 degrees). Each such
#: normal was fitted about both axes under the light the refinement started from, degrees off, and its error passes
#: into the point's albedo amplified by the tangent of the incidence: points lit only near the terminator came out
#: 0.06 to 0.11 too bright, and their tail was most of the body's albedo error. Chosen on config/conditions_geometry.yaml's
#: two `oblique` sets (albedo 0.6, not among the paper's), among 0.3 to 0.6; in the ring's plane (normals turning
#: about the spin axis) the same cut costs k on the tuning grid, so there it is not applied (docs/table2.md, section 0).
FREE_TILT_MIN_MEAN_COS_INCIDENCE = 0.5


def well_lit_points(observations: estimation.Observations, light_dir_cam, min_mean_cos_incidence: float) -> estimation.Observations:
    """The rows of the points whose rows ``light_dir_cam`` lights at a mean incidence cosine of at least
    ``min_mean_cos_incidence``; the other points lose all their rows, the points' numbering is kept."""
    mean_cos = observations.point_means(observations.cos_incidence(light_dir_cam))
    return observations.rows(mean_cos[observations.point_index] >= min_mean_cos_incidence)


def final_observations(stage: CloudStage, settings: dict) -> estimation.Observations:
    """The refined cloud's pure samples that the final fit under the refinement's light uses (:data:`FINAL_MIN_COS_INCIDENCE`;
    where its normals tilted freely, :data:`FREE_TILT_MIN_MEAN_COS_INCIDENCE` too; then :data:`FINAL_MIN_COS_EMISSION`)."""
    pure = stage.pure
    min_observations = settings["min_observations_per_point"]
    lit = lit_samples(pure.observations, pure.refined_light_dir_cam, FINAL_MIN_COS_INCIDENCE, min_observations)
    if pure.normals_tilt_freely:
        lit = well_lit_points(lit, pure.refined_light_dir_cam, FREE_TILT_MIN_MEAN_COS_INCIDENCE)
    return seen_within_emission(lit, FINAL_MIN_COS_EMISSION, min_observations)


def estimate_after_refinement(stage: CloudStage, method: str, known_k: float, final_obs: estimation.Observations) -> tuple[estimation.FitResult, estimation.FitResult, float]:
    """The estimator on the refined cloud's pure samples: (``after``, ``joint``, seconds) as in :class:`CloudFits`;
    ``koizumi_lm``'s final fit on ``final_obs`` (:func:`final_observations`)."""
    pure = stage.pure
    tick = time.perf_counter()
    if method == "koizumi_lm":
        # Two steps: the refinement's light (one k for the body), then the paper's per-point albedo and k under it.
        # The paper's joint fit, light free, is kept beside it (columns *_refined_joint).
        joint = plausible_points(run_estimator(pure.observations, method, light_init=pure.light_dir_cam))
        after = run_estimator(final_obs, method, light_init=pure.refined_light_dir_cam, hold_light=True)
    else:
        joint, after = None, run_estimator(pure.observations, method, known_k=known_k, robust=True)
    refit_seconds = time.perf_counter() - tick
    after = plausible_points(after)
    joint = after if joint is None else joint
    return after, joint, refit_seconds


FIT_FIELDS = tuple(field.name for field in fields(estimation.FitResult))
#: The fits :func:`estimate_cloud_stage` writes (:class:`CloudFits`).
FIT_STAGES = ("before", "after", "joint")


def fit_arrays(result: estimation.FitResult, prefix: str) -> dict:
    """A fit as arrays for one .npz, its fields prefixed (``before_light_dir_cam``, ...)."""
    return {f"{prefix}_{name}": getattr(result, name) for name in FIT_FIELDS}


def fit_from_arrays(data, prefix: str) -> estimation.FitResult:
    """The inverse of :func:`fit_arrays`."""
    values = {name: data[f"{prefix}_{name}"] for name in FIT_FIELDS}
    for name, kind in (("method", str), ("solver", str), ("message", str), ("n_points_fitted", int), ("n_obs", int), ("n_iterations", int), ("nfev", int),
                       ("success", bool), ("cost", float), ("fit_seconds", float)):
        values[name] = kind(values[name])
    return estimation.FitResult(**values)


def light_bound_deg(stage: CloudStage, fit: estimation.FitResult, settings: dict, observations: estimation.Observations | None = None) -> float:
    """The Cramer-Rao standard deviation (deg) of the light for the refined cloud's pure samples under the mission's sensor noise.

    The bound of any unbiased estimate of the light from the observations
    the final fit used (``observations``, by default ``stage.pure``'s), with an albedo and a k per point
    and the normals held, evaluated at that fit (``estimation.fisher``); the
    variance of each sample is the sensor model's for the mean of four
    pixels (``purity.PurityTest.sample_variance``). NaN for noise-free
    images (no sensor model: nothing bounds the error but the model itself)
    or a fit of no point. Points the fit left out are left out here too. No truth is read.
    """
    sensor = stage.mission.get("sensor")
    if not sensor or fit.n_points_fitted == 0:
        return float("nan")
    observations = stage.pure.observations if observations is None else observations
    # A point the fit left out (``plausible_points``: k outside its range) has no albedo and k to evaluate the
    # information at; its rows were not used.
    fitted = np.isfinite(fit.albedo) & np.isfinite(fit.minnaert_k)
    observations = observations.rows(fitted[observations.point_index])
    variance = PurityTest(sensor_from_config(sensor)).sample_variance(observations.brightness)
    bounds = cramer_rao_bounds(
        observations, fit.light_dir_cam, fit.albedo, fit.minnaert_k, variance, min_observations=settings["min_observations_per_point"],
    )
    return float(bounds["light_std_deg"])


def estimate_cloud_stage(inputs: CloudStageInputs, settings: dict, out_npz: Mapping[str, str | Path]) -> None:
    """Each estimator on the reconstructed cloud, and again on the refined one (``refine_stage``): from the mission set alone.

    ``out_npz``: the file of each estimator to run, by name, in the order they
    run. The stage's inputs are read once for all of them. Each file holds
    the fits of :class:`CloudFits` (``fit_arrays``), the seconds of the fits
    after refinement and the k Iwano's baseline was given: the refinement's
    one k for the body, estimated from the images (never the true k). A set
    that failed here or before gets, for every estimator, a file with its
    status; an estimator that fails gets its own, and the others still run.
    ``koizumi_lm``'s final fit holds the light of ``mesh_light_stage`` where
    that stage applied one (``light_source`` "mesh"), else the refinement's;
    there every estimator's fits after refinement see the samples over that
    stage's per-image gains (:func:`mesh_light_of`).
    """
    try:
        stage = read_cloud_stage(inputs, settings)
        held = mesh_light_of(inputs.mesh_light_npz, len(stage.images)) if inputs.mesh_light_npz is not None else None
    except DataFailure as failure:
        reason = record("estimate_cloud", failure)
        for path in out_npz.values():
            write_failed_npz(path, reason)
        return
    known_k = float(stage.pure.refined_minnaert_k)  # the workflow's own k for the body (refine_stage), for Iwano's baseline
    light_source = "refinement" if held is None else "mesh"
    stage = under_mesh_light(stage, held)
    final_obs = final_observations(stage, settings)
    for method, path in out_npz.items():
        try:
            before = estimate_before_refinement(stage, method, known_k)
            after, joint, refit_seconds = estimate_after_refinement(stage, method, known_k, final_obs)
        except DataFailure as failure:
            log.warning("%s: no fit", method)
            write_failed_npz(path, record("estimate_cloud", failure))
            continue
        files.savez(
            path, **fit_arrays(before, "before"), **fit_arrays(after, "after"), **fit_arrays(joint, "joint"),
            refit_seconds=refit_seconds, known_k=known_k, light_source=np.str_(light_source if method == "koizumi_lm" else "estimator"),
            after_light_crb_deg=light_bound_deg(stage, after, settings, final_obs if method == "koizumi_lm" else None),
        )
        log.info("%s: light %s before refinement, %s after", method, np.round(before.light_dir_cam, 6).tolist(), np.round(after.light_dir_cam, 6).tolist())
