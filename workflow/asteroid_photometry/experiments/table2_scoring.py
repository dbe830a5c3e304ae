"""Table 2's scoring: the estimates on each cloud against the truth, the table and its figures.

The only part of Table 2 that reads the truth (rule ``score_cloud``): the
shape model, the mission set's truth file (true poses and light) and the
rendered set's record (true albedo and k per facet). Each cloud point is put
on the body through its registration and matched to its closest facet, whose
normal, albedo and k it is scored against; the light is scored in the camera
frame. The estimates it reads were made from the mission set alone
(:mod:`.table2`, which imports nothing that reads the truth:
``tests/test_architecture.py``). Where the error comes from is taken apart
here too (:func:`oracle_rows`): the same estimator with the truth put in, one
part at a time.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where a table is built: a scoring job has none to build, and pandas takes 0.45 s to import
    import pandas as pd

from asteroid_photometry import estimation
from asteroid_photometry.core import files
from asteroid_photometry.core.failures import check_npz, DataFailure, OK, record, status_counts_line, table_status, write_failed_npz
from asteroid_photometry.estimation.registry import run_estimator
from asteroid_photometry.evaluation import metrics, quality
from asteroid_photometry.evaluation.truth import rendered_truth, true_poses, truth_for_facets
from asteroid_photometry.experiments.mission import read_truth
from asteroid_photometry.experiments.table2 import (
    CloudFits,
    CloudStage,
    CloudStageInputs,
    FIT_STAGES,
    fit_from_arrays,
    plausible_points,
    read_cloud_stage,
)
from asteroid_photometry.from_images import cloud as cloud_lib, refine, register
from asteroid_photometry.world import mesh
from asteroid_photometry.world.cameras import Intrinsics
from asteroid_photometry.world.shape import load_shape_npz

log = logging.getLogger(__name__)

#: The paper's Table 2 (real Hayabusa images), shown beside ours in table2.md and the conditions plot.
PAPER_TABLE2 = {"light_deg_est": 4.21, "light_deg_true": 0.0, "albedo_est": 0.578, "albedo_true": 0.53, "k_est": 0.771, "k_true": 0.7}


@dataclass(frozen=True)
class CloudTruth:
    """The truth at cloud points: each point in the body frame (``points_body``), its closest point on the true
    surface (``surface_body``) and facet (``facets``), that facet's ``albedo``, ``minnaert_k`` and ``normals``;
    the true light (``light_dir_cam``)."""

    points_body: np.ndarray
    surface_body: np.ndarray
    facets: np.ndarray
    albedo: np.ndarray
    minnaert_k: np.ndarray
    normals: np.ndarray
    light_dir_cam: np.ndarray

    def scoring(self, light_dir_cam) -> metrics.Truth:
        """The truth a fit at these points is scored against, under the true light ``light_dir_cam``."""
        return metrics.Truth(light_dir_cam=light_dir_cam, albedo=self.albedo, minnaert_k=self.minnaert_k)


@dataclass(frozen=True)
class ScoringTruth:
    """What the scoring stage reads besides the estimates: the shape model (``shape``, and ``query`` on it), the
    mission set's truth file (``truth``: true poses and light), the rendered set's record (``frames``) and its
    directory (``render_dir``, with the surface maps where it has them)."""

    shape: dict
    query: mesh.SurfaceQuery
    truth: dict
    frames: dict
    render_dir: str | Path


def read_scoring_truth(shape_npz, truth_json, render_dir) -> ScoringTruth:
    """The truth one set is scored against; raises the recorded :class:`DataFailure` of a set whose world stage failed."""
    shape = load_shape_npz(shape_npz)
    return ScoringTruth(
        shape, register.SurfaceQuery(shape["vertices_m"], shape["faces"]), read_truth(truth_json), rendered_truth(render_dir), render_dir,
    )


def truth_at_points(scoring: ScoringTruth, transform, points) -> CloudTruth:
    """The truth (``evaluation.truth``) at cloud-frame ``points``, through the registration ``transform`` (cloud to body frame)."""
    points_body = register.transform_points(transform, points)
    surface_body, facets = scoring.query.closest(points_body)
    albedo, minnaert_k, normals, light = truth_for_facets(facets, scoring.shape, scoring.frames, scoring.render_dir)
    return CloudTruth(points_body, surface_body, facets, albedo, minnaert_k, normals, light)


#: The body's spin axis in its own frame: the rendered body turns about +z (``true_poses``' rotations map it to the
#: cameras' spin axis, which the ``light_err_azimuth_deg*`` columns turn about).
BODY_SPIN_AXIS = np.array([0.0, 0.0, 1.0])


def facet_turn_deg(surface_normals_body, facet_normals_body) -> float:
    """The median turn (degrees) about the body's spin axis from each refined point's surface normal to its true facet's.

    Right-handed about :data:`BODY_SPIN_AXIS`, the sense of the
    ``light_err_azimuth_deg*`` columns. The light step under a sensor takes the
    normals' common turn off on the premise that this is 0
    (``refine.common_turn_deg``); where the refinement keeps facets turned one
    way more often than the other, the final light's azimuth carries about
    minus this (docs/table2.md, section 11).
    """
    if len(surface_normals_body) == 0:
        return float("nan")
    return refine.common_turn_deg(np.asarray(facet_normals_body, float), np.asarray(surface_normals_body, float), BODY_SPIN_AXIS)


def refinement_scores(
    set_id: str, priors: str, method: str, stage: CloudStage, fits: CloudFits, scoring: ScoringTruth, truth: CloudTruth, truth_refined: CloudTruth,
) -> tuple[dict, dict]:
    """The row's scores of the fits after refinement, and the per-point errors before and after (the errors file's arrays).

    ``truth`` and ``truth_refined``: the truth at the cloud's and the refined
    cloud's points. The row's scores of the fit before refinement are
    ``metrics.summary_row``'s, made before.
    """
    before, after, joint, pure, transform = fits.before, fits.after, fits.joint, stage.pure, stage.transform
    light_true = truth.light_dir_cam
    spin_axis_cam = true_poses(scoring.truth)[0, :3, :3] @ BODY_SPIN_AXIS
    scores = {}
    after_row = metrics.summary_row(set_id, after, truth_refined.scoring(light_true))
    normals_before = quality.normal_errors_deg(mesh.transform_normals(transform, stage.oriented.normals), truth.normals)
    normals_after = quality.normal_errors_deg(mesh.transform_normals(transform, pure.normals), truth_refined.normals)
    scores.update({f"{key}_refined": after_row[key] for key in ("light_deg_est", "light_deg_err", "light_dir_err_deg", "albedo_est", "albedo_err", "albedo_rmse", "k_est", "k_err", "k_rmse", "n_points", "n_obs")})
    joint_row = metrics.summary_row(set_id, joint, truth_refined.scoring(light_true))
    scores.update({f"{key}_refined_joint": joint_row[key] for key in ("light_dir_err_deg", "albedo_err", "k_err")})
    scores["refined_light_source"] = "refinement" if method == "koizumi_lm" else "estimator"
    scores["refinement_light_err_deg"] = float(estimation.angle_between_deg(pure.refined_light_dir_cam, light_true))
    scores["refinement_k_err"] = pure.refined_minnaert_k - float(np.median(truth_refined.minnaert_k))
    # The check on the one-k light that needs no truth: the per-point k's robust spread under it.
    fitted_k = after.minnaert_k[np.isfinite(after.minnaert_k)]
    scores["k_spread_refined"] = float(1.4826 * np.median(np.abs(fitted_k - np.median(fitted_k)))) if fitted_k.size else float("nan")
    if method == "koizumi_lm" and scores["k_spread_refined"] > K_SPREAD_WARNING:
        log.warning(
            "set %s, priors %s: the per-point k after refinement spreads by %.3f (robust std), more than %g: the refinement's light "
            "assumes one k for the body, and on a body whose k varies it is off by up to degrees (docs/table2.md, section 7)",
            set_id, priors, scores["k_spread_refined"], K_SPREAD_WARNING,
        )
    for suffix, result in (("", before), ("_refined", after)):
        azimuth, elevation = metrics.light_error_components_deg(result.light_dir_cam, light_true, spin_axis_cam)
        scores[f"light_err_azimuth_deg{suffix}"], scores[f"light_err_elevation_deg{suffix}"] = azimuth, elevation
    scores.update(
        priors=priors,
        normal_err_deg_median=float(np.nanmedian(normals_before)),
        normal_err_deg_median_refined=float(np.nanmedian(normals_after)),
        refit_seconds=fits.refit_seconds,
        refine_candidates=pure.n_candidates,
        refine_accepted=int(len(pure.points)),
        refine_distance_m_median=float(np.median(np.linalg.norm(truth_refined.surface_body - truth_refined.points_body, axis=1))),
        refined_facet_turn_deg=facet_turn_deg(mesh.transform_normals(transform, pure.surface_normals), truth_refined.normals),
    )
    errors = dict(
        points_body=truth.points_body, albedo_error=before.albedo - truth.albedo, k_error=before.minnaert_k - truth.minnaert_k,
        normal_error_deg=normals_before, points_body_refined=truth_refined.points_body,
        albedo_error_refined=after.albedo - truth_refined.albedo, k_error_refined=after.minnaert_k - truth_refined.minnaert_k,
        normal_error_deg_refined=normals_after,
    )
    return scores, errors


ORACLE_COLUMNS = ("light_dir_err_deg", "albedo_err", "k_err", "albedo_rmse", "k_rmse")
#: The estimator whose error is taken apart (:func:`oracle_rows`): the paper's. Three more fits per row, a third of
#: the scoring's time, are not spent on the others.
ORACLE_METHOD = "koizumi_lm"


def oracle_rows(method: str, stage: CloudStage, scoring: ScoringTruth, truth: CloudTruth, settings: dict, known_k: float) -> dict:
    """Where the cloud's error comes from: the same estimator with the truth put in, one part at a time.

    ``truth``: at each registered point, its closest point on the true
    surface (body frame) and that point's facet, albedo and k.
    ``true_normals``: the reconstructed points and cameras, each point's normal
    replaced by its closest facet's. ``true_surface``: each point also moved
    to its closest point on the true surface, still seen through the
    reconstructed cameras. ``true_cameras``: those surface points seen through
    the true cameras as well (the registered images only); what is left then
    is the sampling itself, a point anywhere on a facet of about two pixels
    against the pure pixels of Table 1. All need the registration
    (``stage.transform``: cloud frame to body frame).
    """
    oriented, recon, images, surface_body = stage.oriented, stage.recon, stage.images, truth.surface_body
    scoring_truth = truth.scoring(truth.light_dir_cam)
    poses = recon.body_to_camera()
    all_true_poses = true_poses(scoring.truth)
    true_cameras = {index: all_true_poses[index] for index in poses}
    body_to_cloud = np.linalg.inv(stage.transform)
    normals_body = scoring.shape["normals"][truth.facets]
    row = {}
    # (name, points in the frame of the cameras, those cameras, their intrinsics, body to that frame)
    for name, points, cameras, intrinsics, body_to_frame in (
        ("true_normals", oriented.points, poses, recon.intrinsics(), body_to_cloud),
        ("true_surface", register.transform_points(body_to_cloud, surface_body), poses, recon.intrinsics(), body_to_cloud),
        ("true_cameras", surface_body, true_cameras, Intrinsics(**stage.mission["intrinsics"]), np.eye(4)),
    ):
        swapped = cloud_lib.OrientedCloud(points, mesh.transform_normals(body_to_frame, normals_body), oriented.track_length)
        obs, _ = cloud_lib.cloud_observations(
            swapped, cameras, intrinsics, images, min_cos_emission=settings["min_cos_emission"], min_observations=settings["min_observations_per_point"],
            purity_tolerance=settings.get("purity_tolerance"),
        )
        fitted = metrics.summary_row("", plausible_points(run_estimator(obs, method, known_k=known_k, robust=True)), scoring_truth)
        row.update({f"{key}_{name}": fitted[key] for key in ORACLE_COLUMNS})
    return row


#: Robust spread of the per-point k after refinement above which the one-k light is flagged in the log.
#: On the 16 uniform sets it is 0.0005 to 0.0016 with priors and 0.003 to 0.009 without (full run); k
#: spread uniformly by +-0.05 has a standard deviation of 0.029.
K_SPREAD_WARNING = 0.015


@dataclass(frozen=True)
class ScoringInputs:
    """The files the scoring stage reads besides :class:`CloudStageInputs`: the estimates (``estimate_cloud_stage``'s
    file of each estimator, by name, in the order the rows are written), the shape model, the mission set's truth file
    and the rendered set (truth)."""

    estimates_npz: Mapping[str, str | Path]
    shape_npz: str | Path
    truth_json: str | Path
    render_dir: str | Path

    @classmethod
    def from_rule_input(cls, rule_input, methods) -> ScoringInputs:
        """The files named as rule ``score_cloud`` names its inputs (``snakemake.input``); its ``estimates``, those of ``methods`` in order."""
        if len(rule_input.estimates) != len(methods):
            raise ValueError(f"{len(rule_input.estimates)} estimate files for {len(methods)} estimators {list(methods)}")
        return cls(dict(zip(methods, rule_input.estimates)), rule_input.shape, rule_input.truth, rule_input.render_truth)


class _Once:
    """A value computed at its first use and kept; a :class:`DataFailure` computing it is kept too, and raised at every use."""

    def __init__(self, compute):
        self._compute, self._value, self._failure = compute, None, None
        self._done = False

    def __call__(self):
        if not self._done:
            try:
                self._value = self._compute()
            except DataFailure as failure:
                self._failure = failure
            self._done = True
        if self._failure is not None:
            raise self._failure
        return self._value


@dataclass(frozen=True)
class _SharedScoring:
    """What the rows of one cloud share, each read or computed once, when a row first needs it: the stage, the
    truth, and the truth at the cloud's and the refined cloud's points."""

    stage: _Once
    scoring: _Once
    truth: _Once
    truth_refined: _Once

    @classmethod
    def of(cls, inputs: CloudStageInputs, scoring_inputs: ScoringInputs, settings: dict) -> _SharedScoring:
        stage = _Once(lambda: read_cloud_stage(inputs, settings, observations=False))
        scoring = _Once(lambda: read_scoring_truth(scoring_inputs.shape_npz, scoring_inputs.truth_json, scoring_inputs.render_dir))
        truth = _Once(lambda: truth_at_points(scoring(), stage().transform, stage().oriented.points))
        truth_refined = _Once(lambda: truth_at_points(scoring(), stage().transform, stage().pure.points))
        return cls(stage, scoring, truth, truth_refined)


def score_cloud_stage(
    inputs: CloudStageInputs, scoring_inputs: ScoringInputs, set_id: str, imaging: str, priors: str, settings: dict,
    out_json: Mapping[str, str | Path], out_npz: Mapping[str, str | Path],
) -> None:
    """The estimates on one cloud scored against the truth: each estimator's row of Table 2 (``out_json``, by
    estimator as ``scoring_inputs.estimates_npz``) and its per-point errors (``out_npz``).

    The stage and the truth are read once for all the rows. A set that failed
    here or before (reconstruction, registration, refinement, estimates) gets
    a row with its ``status`` (the reason), what is known of its
    reconstruction and registration, and no estimates; one estimator's
    failure leaves the others' rows as they are.
    """
    shared = _SharedScoring.of(inputs, scoring_inputs, settings)
    for method, estimates_npz in scoring_inputs.estimates_npz.items():
        try:
            row, errors = _score_cloud(estimates_npz, shared, method, set_id, priors, settings)
        except DataFailure as failure:
            log.warning("%s: no row", method)
            reason = record("score_cloud", failure)
            row = _failed_row(inputs, method, set_id, priors, reason)
            row["imaging"] = imaging
            write_failed_npz(out_npz[method], reason)
            files.write_json(out_json[method], row)
            continue
        row["imaging"] = imaging
        files.write_json(out_json[method], row)
        files.savez(out_npz[method], **errors)
        log.info("table 2 row: %s", json.dumps(row))


def _failed_row(inputs: CloudStageInputs, method: str, set_id: str, priors: str, reason: str) -> dict:
    """The row of a set that failed: its status, and what its reconstruction and registration recorded."""
    row = {"set_id": set_id, "priors": priors, "method": method, "status": table_status(reason)}
    report_path = Path(inputs.reconstruction_dir) / "report.json"
    if report_path.exists():
        report = json.loads(report_path.read_text())
        row.update(n_images_registered=report["n_images_registered"], reproj_rms_px=report["reproj_rms_px"])
    registration = json.loads(Path(inputs.registration_json).read_text())
    row.update({key: value for key, value in registration.items() if key not in ("status", "reason")})
    return row


def _score_cloud(estimates_npz, shared: _SharedScoring, method: str, set_id: str, priors: str, settings: dict) -> tuple[dict, dict]:
    """One estimator's row and its per-point errors: its estimates read, the truth at the points (``shared``), the scores."""
    with np.load(estimates_npz) as data:
        check_npz(data, estimates_npz)
        before, after, joint = (fit_from_arrays(data, prefix) for prefix in FIT_STAGES)
        refit_seconds, known_k = float(data["refit_seconds"]), float(data["known_k"])
        light_crb_deg = float(data["after_light_crb_deg"]) if "after_light_crb_deg" in data.files else float("nan")
        light_source = str(data["light_source"]) if "light_source" in data.files else None
    stage, scoring, truth = shared.stage(), shared.scoring(), shared.truth()
    # A fit of no point fails the row here.
    row = metrics.summary_row(set_id, before, truth.scoring(truth.light_dir_cam))
    fits = CloudFits(before, after, joint, refit_seconds)
    truth_refined = shared.truth_refined()
    scores, errors = refinement_scores(set_id, priors, method, stage, fits, scoring, truth, truth_refined)
    row.update(scores)
    if light_source is not None:
        row["refined_light_source"] = light_source
    report = stage.report
    row.update(
        n_images_registered=report["n_images_registered"], reproj_rms_px=report["reproj_rms_px"],
        cam_pos_rms_m=report.get("cam_pos_rms_m"), prior_overfit=report.get("prior_overfit"),
    )
    row.update(quality.camera_errors(stage.recon.body_to_camera(), true_poses(scoring.truth), stage.recon.prior_positions, report["world_frame"]))
    row.update(stage.registration)
    row["status"] = table_status()
    row["light_crb_deg_final"] = light_crb_deg
    if method == "iwano_linear":
        row["known_k"] = known_k
        row["known_k_err"] = known_k - float(np.median(truth.minnaert_k))
    if method == ORACLE_METHOD:
        row.update(oracle_rows(method, stage, scoring, truth, settings, known_k))
    return row, errors


TABLE2_LEAD = ["set_id", "imaging", "priors", "method", "status"]
#: The final estimate of every row: after every stage, the refinement included.
FINAL_COLUMNS = {"light_dir_err_deg_final": "light_dir_err_deg_refined", "albedo_err_final": "albedo_err_refined", "k_err_final": "k_err_refined"}
#: The final light error over its bound (:func:`light_err_over_bound`), and the Cramer-Rao deviation that bound allows for.
BOUND_COLUMNS = ["light_err_over_bound_final", "light_crb_deg_final"]
#: How many Cramer-Rao standard deviations the light's bound allows where the noise alone allows less than the fixed bound.
CRB_FACTOR = 3.0


def light_err_over_bound(table: pd.DataFrame) -> pd.Series:
    """Each row's final light error over its bound: the condition's (``metrics.table2_bounds``), or, where the noise
    alone allows less, ``CRB_FACTOR`` times the Cramer-Rao deviation of the light for the observations used
    (``light_crb_deg_final``, NaN for noise-free images). 1 or less is within the bound."""
    import pandas as pd
    fixed = table["imaging"].map(lambda imaging: metrics.table2_bounds(imaging)["light_dir_err_deg"]).astype(float)
    crb = table["light_crb_deg_final"] if "light_crb_deg_final" in table else pd.Series(np.nan, index=table.index)
    bound = np.fmax(fixed, CRB_FACTOR * crb.astype(float))
    return table["light_dir_err_deg_final"].abs() / bound


def write_table2(summary_paths, out_csv, out_markdown) -> None:
    import pandas as pd
    rows = [{"status": OK, **json.loads(Path(path).read_text())} for path in summary_paths]
    table = metrics.without_timings(pd.DataFrame(rows))
    for final, source in FINAL_COLUMNS.items():
        table[final] = table[source] if source in table else np.nan
    if "light_crb_deg_final" not in table:
        table["light_crb_deg_final"] = np.nan
    table["light_err_over_bound_final"] = light_err_over_bound(table)
    lead = TABLE2_LEAD + list(FINAL_COLUMNS) + BOUND_COLUMNS
    table = table[lead + [c for c in table if c not in lead]].sort_values(TABLE2_LEAD[:4], kind="stable")
    files.write_csv(table, out_csv)
    files.write_text(out_markdown, table2_markdown(table))
    log.info("Table 2: %s", status_counts_line(table, "rows"))


def table2_markdown(table: pd.DataFrame) -> str:
    import pandas as pd
    paper = PAPER_TABLE2
    lines = [
        "# Table 2: from images alone", "",
        "Sparse pycolmap reconstruction of each set (with and without navigation position priors), an oriented cloud "
        "with visibility, the estimators, then the photometric refinement (points moved to where the images show their "
        "samples pure, normals turned about the spin axis to fit them) and the estimators again. After refinement the paper's "
        "estimator (koizumi_lm) takes the refinement's light, fitted to the pure samples with one Minnaert k for the body, and fits "
        "each point's albedo and k under it (`light err ref.`); its own joint fit, light free, is `light err joint`. The other "
        "estimators fit their own light. Scored against the shape model after registration. The paper's Table 2 (real Hayabusa images, Bundler + PMVS2): light "
        f"{paper['light_deg_est']} deg (reference about 0), albedo {paper['albedo_est']} (reference {paper['albedo_true']}), "
        f"k {paper['k_est']} (reference about {paper['k_true']}).", "",
    ]
    columns = [
        ("set_id", "set", None), ("status", "status", None), ("n_images_registered", "images", None), ("reproj_rms_px", "reproj px", 2),
        ("cam_pos_rms_m", "cam-prior m", 2), ("prior_overfit", "overfit", None), ("registration_ok", "reg ok", None),
        ("registration_rms_rel", "reg RMS rel", 4), ("accuracy_rel_median", "acc rel", 4), ("completeness", "compl.", 3),
        ("n_points", "points", None), ("n_points_refined", "points ref.", None), ("light_dir_err_deg", "light err", 3),
        ("light_dir_err_deg_refined", "light err ref.", 3), ("light_err_elevation_deg_refined", "of it elev. ref.", 3),
        ("light_dir_err_deg_refined_joint", "light err joint", 3),
        ("albedo_err", "albedo err", 4), ("albedo_err_refined", "albedo err ref.", 4), ("k_err", "k err", 4),
        ("k_err_refined", "k err ref.", 4), ("normal_err_deg_median", "normal err", 1), ("normal_err_deg_median_refined", "normal err ref.", 1),
    ]
    for (imaging, priors, method), group in table.groupby(["imaging", "priors", "method"], sort=True):
        lines += [f"## imaging {imaging}, priors {priors}, {method}", "", status_counts_line(group, keys=("set_id",)), ""]
        lines += ["| " + " | ".join(title for _, title, _ in columns) + " |", "|" + "---|" * len(columns)]
        for _, row in group.iterrows():
            cells = []
            for key, _, digits in columns:
                value = row.get(key)
                cells.append(metrics.text_cell(value) if digits is None or pd.isna(value) else f"{value:.{digits}f}")
            lines.append("| " + " | ".join(cells) + " |")
        worst = {key: group[key].abs().max() for key in ("light_dir_err_deg_refined", "albedo_err_refined", "k_err_refined") if key in group}
        lines += ["", "Worst after refinement: " + ", ".join(f"{k} {v:.3g}" for k, v in worst.items()) + f"; registered {int(group.registration_ok.fillna(False).astype(bool).sum())}/{len(group)}", ""]
    lines += error_decomposition_markdown(table)
    return "\n".join(lines)


def error_decomposition_markdown(table: pd.DataFrame) -> list[str]:
    """Median absolute errors over the registered sets as the truth is put in, one part at a time (:func:`oracle_rows`)."""
    if "k_err_true_cameras" not in table:
        return []
    lines = ["## Where the error comes from", "",
             "Median over the registered sets of the absolute errors, with the truth put in one part at a time "
             f"(same images, same estimator; `_true_*` columns of table2.csv; {ORACLE_METHOD} only).", ""]
    decomposed = table.registration_ok.fillna(False).astype(bool) & (table.status == OK) & table.k_err_true_cameras.notna()
    for (imaging, priors, method), group in table[decomposed].groupby(["imaging", "priors", "method"], sort=True):
        lines += [f"### imaging {imaging}, priors {priors}, {method}", "", "| | light err (deg) | albedo err | k err |", "|---|---|---|---|"]
        for suffix, title in metrics.TABLE2_STAGES:
            cells = [f"{group[f'{key}{suffix}'].abs().median():.4g}" for key in ("light_dir_err_deg", "albedo_err", "k_err")]
            lines.append(f"| {title} | " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def write_table2_plots(table_csv, cloud_errors_npz, method: str, title: str, out_stages_png, out_cloud_png, out_conditions_png) -> None:
    """Table 2's figures: errors from cloud to truth per set, the final errors per imaging condition against the paper's,
    and one set's cloud coloured by its per-point errors."""
    import pandas as pd
    from asteroid_photometry.evaluation import plots

    table = pd.read_csv(table_csv)
    plots.plot_table2_stages(table, method, out_stages_png)
    plots.plot_table2_conditions(table, method, PAPER_TABLE2, out_conditions_png)
    with np.load(cloud_errors_npz) as data:
        if "status" in data.files:
            plots.plot_message(f"{title}\n\nno cloud: {data['reason']}", out_cloud_png)
            return
        # The refinement moves the samples: the refined errors belong to other points.
        before, after = data["points_body"], data["points_body_refined"]
        values = {
            "k error": (before, data["k_error"]), "refined k error": (after, data["k_error_refined"]),
            "normal error (deg)": (before, data["normal_error_deg"]), "refined normal error (deg)": (after, data["normal_error_deg_refined"]),
        }
    plots.plot_values_on_body(values, title, out_cloud_png)
