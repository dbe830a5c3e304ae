"""How good a reconstructed point cloud is, once it sits in the body frame.

After :func:`asteroid_photometry.from_images.register.register_to_shape` has placed a
reconstruction on the shape model, this module scores it against the true
surface, the usual pair of multi-view-stereo measures plus normals:

- **accuracy**: distance from each reconstructed point to the true surface
  (median and 90th percentile, in metres and relative to the body length);
- **completeness**: the fraction of the true surface within a distance
  threshold of some reconstructed point, estimated on uniform, area-weighted
  samples of the surface (default threshold 1 % of the body length);
- **normals**: the angle between each point's normal, turned into the body
  frame, and the normal of its closest facet (median in degrees), and the
  fraction of flipped normals (angle over 90 degrees).

:func:`point_scores` gives the per-point values (distance, closest facet,
normal error), so each point can also be scored against its true facet's
albedo and Minnaert k. Lengths in metres, angles in degrees as named.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from asteroid_photometry.from_images.reconstruct import rms, similarity_alignment
from asteroid_photometry.world.cameras import camera_centres_body
from asteroid_photometry.world.mesh import (
    body_length_m,
    sample_surface,
    SurfaceQuery,
    transform_normals,
    transform_points,
)
from asteroid_photometry.world.shape import facet_geometry

#: Default completeness threshold, as a fraction of the body length.
COMPLETENESS_THRESHOLD_REL = 0.01
#: Default number of uniform surface samples for completeness (about one
#: per 2 m x 2 m on Itokawa: the estimate's sampling error is below 0.002).
N_SURFACE_SAMPLES = 100_000


@dataclass(frozen=True)
class PointScores:
    """Per-point comparison with the true surface (body frame).

    ``distance_m`` (N,): unsigned distance to the surface; ``facet_id`` (N,):
    index of the closest facet; ``normal_error_deg`` (N,): angle between the
    point's normal and that facet's outward normal, 0..180, NaN where no
    normal was given or it has zero length.
    """

    distance_m: np.ndarray
    facet_id: np.ndarray
    normal_error_deg: np.ndarray


@dataclass(frozen=True)
class ReconstructionQuality:
    """Accuracy, completeness and normal errors of one reconstruction.

    ``*_rel`` are fractions of ``body_length_m`` (the longest extent, see
    :func:`asteroid_photometry.world.mesh.body_length_m`). Normal fields are
    NaN when no normals were given. ``normal_error_median_unsigned_deg``
    ignores orientation (``min(a, 180 - a)``), for clouds whose normals are
    not consistently oriented.
    """

    n_points: int
    body_length_m: float
    accuracy_median_m: float
    accuracy_p90_m: float
    accuracy_median_rel: float
    accuracy_p90_rel: float
    completeness: float
    completeness_threshold_m: float
    normal_error_median_deg: float
    normal_error_median_unsigned_deg: float
    flipped_normal_fraction: float

    def summary(self) -> dict:
        """The fields as a JSON-ready dict."""
        return {key: (value if isinstance(value, int) else float(value)) for key, value in asdict(self).items()}


def _finite_rows(points, normals=None):
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    keep = np.all(np.isfinite(points), axis=1)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != points.shape:
            raise ValueError(f"normals must have the shape of points {points.shape}, got {normals.shape}")
        normals = normals[keep]
    return points[keep], normals


def normal_errors_deg(normals_body, facet_normals) -> np.ndarray:
    """Angle in degrees (0..180) between each normal and the matching true facet normal; NaN for zero normals."""
    normals_body = np.asarray(normals_body, dtype=np.float64)
    lengths = np.linalg.norm(normals_body, axis=1)
    cosines = np.einsum("ij,ij->i", normals_body, facet_normals) / np.where(lengths > 0, lengths, np.nan)
    return np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))


def point_scores(points_body_m, normals_body, vertices_m, faces, surface: SurfaceQuery | None = None) -> PointScores:
    """Distance to the true surface, closest facet and normal error of each body-frame point.

    ``normals_body`` (N,3) or None; rows of ``points_body_m`` with NaN give
    NaN distance, facet id -1 and NaN normal error. ``surface`` reuses a
    :class:`~asteroid_photometry.world.mesh.SurfaceQuery` of the same mesh.
    """
    points_body_m = np.asarray(points_body_m, dtype=np.float64)
    if points_body_m.ndim != 2 or points_body_m.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points_body_m.shape}")
    surface = surface if surface is not None else SurfaceQuery(vertices_m, faces)
    finite = np.all(np.isfinite(points_body_m), axis=1)
    distance_m = np.full(len(points_body_m), np.nan)
    facet_id = np.full(len(points_body_m), -1, dtype=np.int64)
    closest_points, closest_ids = surface.closest(points_body_m[finite])
    facet_id[finite] = closest_ids
    distance_m[finite] = np.linalg.norm(closest_points - points_body_m[finite], axis=1)
    normal_error_deg = np.full(len(points_body_m), np.nan)
    if normals_body is not None:
        normals_body = np.asarray(normals_body, dtype=np.float64)
        if normals_body.shape != points_body_m.shape:
            raise ValueError(f"normals must have the shape of points {points_body_m.shape}, got {normals_body.shape}")
        _, facet_normals, _ = facet_geometry(vertices_m, faces)
        normal_error_deg[finite] = normal_errors_deg(normals_body[finite], facet_normals[facet_id[finite]])
    return PointScores(distance_m=distance_m, facet_id=facet_id, normal_error_deg=normal_error_deg)


def completeness(points_body_m, vertices_m, faces, threshold_m, n_samples=N_SURFACE_SAMPLES, seed=0) -> float:
    """Fraction of the true surface area within ``threshold_m`` of some reconstructed point.

    Estimated on ``n_samples`` uniform (area-weighted) samples of the
    surface, each looked up in a k-d tree of the points.
    """
    from scipy.spatial import cKDTree

    points_body_m, _ = _finite_rows(points_body_m)
    if len(points_body_m) == 0:
        return 0.0
    samples, _ = sample_surface(vertices_m, faces, n_samples, seed)
    distances, _ = cKDTree(points_body_m).query(samples, k=1, distance_upper_bound=threshold_m)
    return float(np.mean(distances <= threshold_m))


def reconstruction_quality(
    points,
    normals,
    vertices_m,
    faces,
    *,
    transform=None,
    completeness_threshold_m: float | None = None,
    completeness_threshold_rel: float = COMPLETENESS_THRESHOLD_REL,
    n_surface_samples: int = N_SURFACE_SAMPLES,
    seed: int = 0,
) -> ReconstructionQuality:
    """Accuracy, completeness and normal errors of a reconstruction against the true mesh.

    ``points`` (N,3) and ``normals`` (N,3) or None are in the body frame, or
    in the reconstruction's frame with ``transform`` the 4x4 similarity to
    the body frame (``RegistrationResult.transform``; normals turn by its
    rotation only). All points count (an outlier is an inaccurate point);
    NaN rows are dropped. The completeness threshold is
    ``completeness_threshold_m`` if given, else ``completeness_threshold_rel``
    of the body length.
    """
    points, normals = _finite_rows(points, normals)
    if len(points) == 0:
        raise ValueError("no finite points to score")
    if transform is not None:
        points = transform_points(transform, points)
        normals = None if normals is None else transform_normals(transform, normals)
    length_m = body_length_m(vertices_m, faces)
    if completeness_threshold_m is None:
        threshold_m = completeness_threshold_rel * length_m
    else:
        threshold_m = float(completeness_threshold_m)
    scores = point_scores(points, normals, vertices_m, faces)
    accuracy_median_m, accuracy_p90_m = (float(value) for value in np.percentile(scores.distance_m, [50, 90]))
    angles = scores.normal_error_deg[np.isfinite(scores.normal_error_deg)]
    if len(angles):
        normal_error_median_deg = float(np.median(angles))
        normal_error_median_unsigned_deg = float(np.median(np.minimum(angles, 180.0 - angles)))
        flipped_normal_fraction = float(np.mean(angles > 90.0))
    else:
        normal_error_median_deg = normal_error_median_unsigned_deg = flipped_normal_fraction = float("nan")
    return ReconstructionQuality(
        n_points=int(len(points)),
        body_length_m=length_m,
        accuracy_median_m=accuracy_median_m,
        accuracy_p90_m=accuracy_p90_m,
        accuracy_median_rel=accuracy_median_m / length_m,
        accuracy_p90_rel=accuracy_p90_m / length_m,
        completeness=completeness(points, vertices_m, faces, threshold_m, n_surface_samples, seed),
        completeness_threshold_m=threshold_m,
        normal_error_median_deg=normal_error_median_deg,
        normal_error_median_unsigned_deg=normal_error_median_unsigned_deg,
        flipped_normal_fraction=flipped_normal_fraction,
    )


def camera_errors(body_to_camera: dict, true_body_to_camera: np.ndarray, prior_positions: np.ndarray | None, world_frame: str) -> dict:
    """How far a reconstruction's cameras are from the true ones: the scoring half of its report.

    ``body_to_camera``: the estimated pose of every registered image (set
    index -> 4x4), in the body frame when ``world_frame == "body"`` (priors
    on), else in a similarity frame of the model's own; then the cameras are
    first mapped onto the true ones by the least-squares similarity of their
    centres (``alignment_scale``: its scale). ``cam_pos_true_rms_m``: RMS
    distance of the centres (metres); ``cam_rot_true_rms_deg``: RMS angle of
    ``R_est R_true^T``; ``prior_pos_true_rms_m``: the navigation priors'
    own RMS error, with priors.
    """
    indices = sorted(body_to_camera)
    estimated = np.array([body_to_camera[index] for index in indices], dtype=float).reshape(-1, 4, 4)
    true = np.asarray(true_body_to_camera, dtype=float)[indices].reshape(-1, 4, 4)
    centres, true_centres = camera_centres_body(estimated), camera_centres_body(true)
    rotations = estimated[:, :3, :3]
    errors = {"prior_pos_true_rms_m": None, "alignment_scale": None}
    if world_frame == "body":
        if prior_positions is not None:
            errors["prior_pos_true_rms_m"] = rms(np.asarray(prior_positions, dtype=float)[indices] - true_centres)
    elif len(centres) >= 3:
        scale, rotation, translation = similarity_alignment(centres, true_centres)
        centres = scale * centres @ rotation.T + translation
        rotations = rotations @ rotation.T  # body from model frame is `rotation`: R_cam_from_body = R_cam_from_model R^T
        errors["alignment_scale"] = scale
    else:
        centres, rotations = np.full_like(centres, np.nan), np.full_like(rotations, np.nan)
    relative = np.einsum("nij,nkj->nik", rotations, true[:, :3, :3])
    angles_deg = np.degrees(np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    errors["cam_pos_true_rms_m"] = rms(centres - true_centres)
    errors["cam_rot_true_rms_deg"] = float(np.sqrt(np.mean(angles_deg**2))) if len(angles_deg) else float("nan")
    return errors
