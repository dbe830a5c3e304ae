"""Place a reconstructed point cloud on the reference shape model (body frame).

A reconstruction (structure from motion + multi-view stereo) lives in its
own frame: without priors, an arbitrary similarity (rotation, translation
and an unknown scale) away from the body frame; with position priors,
roughly in the body frame already. Before its normals, albedo and Minnaert
k can be scored point by point against the truth, it has to be placed on
the shape model. :func:`register_to_shape` does that in two stages, a
coarse global alignment followed by a local refinement:

1. **Global rough alignment, no initial guess.** The source is thinned on
   a voxel grid and stray points (outliers) are removed by their distance
   to their neighbours. Both clouds are then normalised to the same size
   (centroid at the origin, RMS radius of the thinned surface 1), because
   open3d's feature-based RANSAC estimates a rigid transform only. FPFH features + RANSAC
   (``registration_ransac_based_on_feature_matching``) give one candidate
   pose; a principal-axis alignment gives another. Itokawa is elongated and
   nearly symmetric, so each candidate is also tried turned by 180 degrees
   about each principal axis of the body (the poses RANSAC confuses), and
   each of these is polished by a short scaled ICP and scored against the
   true surface. When no candidate fits, the source is re-sized by a few
   factors (a hole or a missing cap biases the size estimate) and the
   search repeats.
2. **ICP.** The best candidate is refined by point-to-point ICP with
   scaling (``TransformationEstimationPointToPoint(with_scaling=True)``),
   then by rigid point-to-plane ICP against dense surface samples with the
   facets' normals. The best other pose of the search is refined the same
   way, to measure how clearly the chosen pose wins (``ambiguity``).

The result is scored against the exact mesh (open3d ``RaycastingScene``),
not against samples. ``success`` is decided by :data:`SUCCESS_RMS_REL`,
:data:`SUCCESS_FITNESS` and :data:`SUCCESS_AMBIGUITY` (see there for why
these values).

Frames and units follow the package conventions: the body frame is the
shape model's, lengths in metres. The returned ``transform`` maps the
input frame to the body frame, ``x_body = scale * R @ x + t``; normals turn
by ``R`` only. Reflections are not searched: a reconstruction is assumed to
be right-handed.

:func:`point_to_surface_distance` and :func:`closest_facet` are also the
building blocks of the scores in :mod:`asteroid_photometry.evaluation.quality`.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from asteroid_photometry.core.failures import DataFailure
from asteroid_photometry.world.mesh import (
    _as_mesh,
    _as_points,
    body_length_m,
    decompose_similarity,
    rotation_angle_deg,
    sample_surface,
    similarity_transform,
    SurfaceQuery,
    transform_points,
)
from asteroid_photometry.world.shape import facet_geometry

logger = logging.getLogger(__name__)

# ---------------------------------------------------------------- thresholds
#
# ``success`` needs the three conditions below, and a plausible scale: within
# a factor of 2 of the size estimate (scaled ICP can shrink a cloud that fits
# nowhere onto one spot of the surface, where it then fits perfectly).
# Measured on Itokawa (tests/test_register.py, and trials on the Gaskell
# model with 20,000 points): correct poses of clouds with 0.2-0.8 % noise,
# 20-40 % outliers, holes of 30-50 % and missing caps give RMS 0.2-0.9 %,
# fitness 0.95-1.0 and ambiguity 0.03-0.3; a sphere or a random blob gives
# fitness 0.49-0.64; an ellipsoid of Itokawa's size fits to RMS 0.96 % at
# fitness 0.96, and only its ambiguity (0.78) rejects it; Ostro's model
# turned end over end and polished by ICP alone reaches fitness 0.97 at
# RMS 1.02 %. A correct pose of a cloud noisier than about 1 % of the length
# fails the RMS test: at that noise the tests cannot tell it from a wrong one.

#: Inlier band: a registered point within this fraction of the body length
#: from the true surface counts as an inlier (fitness, inlier RMSE).
INLIER_DISTANCE_REL = 0.025
#: RMS distance of the inliers to the true surface below this fraction of
#: the body length. A correct pose leaves the cloud's own noise; points
#: spread evenly over the inlier band (a pose that is wrong but "nearly
#: fits") give INLIER_DISTANCE_REL / sqrt(3) = 1.4 %.
SUCCESS_RMS_REL = 0.01
#: Fitness above this: the fraction of the registered points (after outlier
#: removal) within the inlier band. Fails shapes that are not the body.
SUCCESS_FITNESS = 0.9
#: Ambiguity below this: on the chosen pose's inliers, the best other pose
#: tried (turned by more than 45 degrees) must have a truncated mean-square
#: distance at least twice the chosen pose's (an RMS sqrt(2) larger). Fails clouds whose pose is not
#: determined by their shape: near-ellipsoids, or patches too small or too
#: smooth, where Itokawa turned end over end fits about as well. Not
#: applied when no other pose was tried (``global_search=False``).
SUCCESS_AMBIGUITY = 0.5
#: Default voxel size for features and ICP, as a fraction of the body length.
VOXEL_SIZE_REL = 0.02

# Factors by which the normalised source is re-sized when the global search
# at the size estimate finds no pose that passes. A hole or a missing cap
# shrinks a cloud's RMS radius, so the normalised source comes out too large:
# shrinking is tried first.
_RESIZE_FACTORS = (1.0, 0.8, 1.2, 0.65)
# Candidates turned by more than this from the best count as other poses
# (closer ones are mostly starts in the best pose's basin that the short
# candidate ICP has not quite brought home).
_DISTINCT_POSE_DEG = 45.0
# Other poses of the global search refined by the final ICP to measure the
# ambiguity, and the source points they are refined and scored on.
_RIVALS_REFINED = 2
_RIVAL_POINTS = 3000
# A pose whose scale differs from the size estimate by more than this factor
# is implausible (see _Candidate).
_SCALE_TOLERANCE = 2.0
# Source points on which each global candidate is polished and scored.
_CANDIDATE_POINTS = 1500
# The four proper rotations that map the principal axes onto themselves:
# identity and the 180-degree turns about each axis.
_AXIS_FLIPS = ((1.0, 1.0, 1.0), (1.0, -1.0, -1.0), (-1.0, 1.0, -1.0), (-1.0, -1.0, 1.0))


# ---------------------------------------------------------------- the result


@dataclass(frozen=True)
class RegistrationResult:
    """Where a reconstructed cloud sits on the shape model, and how well it fits.

    - ``transform`` (4,4): the similarity from the input frame to the body
      frame, ``x_body = scale * rotation @ x + translation_m``.
    - ``success``: ``rms_distance_rel < success_rms_rel``, ``fitness >
      success_fitness`` and ``ambiguity < success_ambiguity`` (the
      thresholds used are stored; defaults ``SUCCESS_*``), and ``scale``
      within a factor of 2 of the estimate from the clouds' sizes.
    - ``fitness``: fraction of the registered points (the input after
      outlier removal and voxel thinning) within ``inlier_distance_m`` of
      the true surface; ``inlier_rmse_m`` their RMS distance to it;
      ``rms_distance_rel`` = ``inlier_rmse_m / body_length_m``.
    - ``inlier_fraction_all``: the same fraction over all finite input
      points (outliers included).
    - ``ambiguity``: on the chosen pose's inliers, its mean-square distance
      over the truncated one of the best other pose of the global search
      (0: unique, 1: another pose fits as well; NaN when none was tried).
    - ``seconds_global`` / ``seconds_icp``: wall time of the rough alignment
      (sampling the reference, thinning and cleaning the input, features,
      RANSAC, the candidate search) and of the final ICP (scaled
      point-to-point, then point-to-plane).
    """

    transform: np.ndarray
    scale: float
    rotation: np.ndarray
    translation_m: np.ndarray
    success: bool
    fitness: float
    inlier_rmse_m: float
    rms_distance_rel: float
    inlier_fraction_all: float
    body_length_m: float
    inlier_distance_m: float
    voxel_size_m: float
    seconds_global: float
    seconds_icp: float
    n_points_input: int
    n_points_registered: int
    n_candidates: int
    ambiguity: float
    success_rms_rel: float
    success_fitness: float
    success_ambiguity: float
    plausible_scale: bool = True

    @property
    def failure_reason(self) -> str | None:
        """Why ``success`` is False, in words (None when it is True)."""
        if self.success:
            return None
        reasons = []
        if not self.ambiguity < self.success_ambiguity and np.isfinite(self.ambiguity):
            reasons.append(f"no unambiguous pose (another pose fits nearly as well: ambiguity {self.ambiguity:.2f}, limit {self.success_ambiguity:g})")
        if not self.fitness > self.success_fitness:
            reasons.append(f"fitness {self.fitness:.2f} of the points on the surface (needs > {self.success_fitness:g})")
        if not self.rms_distance_rel < self.success_rms_rel:
            reasons.append(f"inlier RMS {100 * self.rms_distance_rel:.2f} % of the body length (limit {100 * self.success_rms_rel:g} %)")
        if not self.plausible_scale:
            reasons.append(f"implausible scale {self.scale:.3g}")
        return "registration failed: " + "; ".join(reasons or ["no pose found"])

    @property
    def seconds(self) -> float:
        return self.seconds_global + self.seconds_icp

    def apply(self, points) -> np.ndarray:
        """Input-frame points (N,3) in the body frame (metres)."""
        return transform_points(self.transform, points)

    def apply_normals(self, normals) -> np.ndarray:
        """Input-frame unit normals (N,3) turned into the body frame."""
        return np.asarray(normals, dtype=np.float64) @ self.rotation.T

    def summary(self) -> dict:
        """The scalar fields as a JSON-ready dict (the transform as nested lists)."""
        return {
            "success": bool(self.success),
            "scale": self.scale,
            "transform": self.transform.tolist(),
            "fitness": self.fitness,
            "inlier_rmse_m": self.inlier_rmse_m,
            "rms_distance_rel": self.rms_distance_rel,
            "inlier_fraction_all": self.inlier_fraction_all,
            "body_length_m": self.body_length_m,
            "inlier_distance_m": self.inlier_distance_m,
            "voxel_size_m": self.voxel_size_m,
            "seconds_global": self.seconds_global,
            "seconds_icp": self.seconds_icp,
            "n_points_input": self.n_points_input,
            "n_points_registered": self.n_points_registered,
            "n_candidates": self.n_candidates,
            "ambiguity": self.ambiguity,
            "success_rms_rel": self.success_rms_rel,
            "success_fitness": self.success_fitness,
            "success_ambiguity": self.success_ambiguity,
            "plausible_scale": self.plausible_scale,
        }


# ---------------------------------------------------------------- helpers


def _point_cloud(points, normals=None):
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64)))
    if normals is not None:
        cloud.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, dtype=np.float64))
    return cloud


def _centre_and_rms_radius(points) -> tuple[np.ndarray, float]:
    centre = points.mean(axis=0)
    return centre, float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1))))


def _axes_of(points) -> np.ndarray:
    """Principal axes (columns, largest variance first, right-handed) of a centred cloud."""
    eigenvalues, axes = np.linalg.eigh(np.cov(points.T))
    axes = axes[:, np.argsort(eigenvalues)[::-1]]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return axes


def _features(cloud, voxel):
    """Normals re-estimated at the voxel scale (keeping the given orientation) and FPFH features."""
    import open3d as o3d

    reference_normals = np.asarray(cloud.normals).copy()
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    normals = np.asarray(cloud.normals)
    flip = np.sum(normals * reference_normals, axis=1) < 0
    normals[flip] = -normals[flip]
    cloud.normals = o3d.utility.Vector3dVector(normals)
    return o3d.pipelines.registration.compute_fpfh_feature(
        cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel, max_nn=100)
    )


def _icp(source, target, init, distances, *, with_scaling, point_to_plane=False, max_iteration=30):
    import open3d as o3d

    reg = o3d.pipelines.registration
    if point_to_plane:
        estimation = reg.TransformationEstimationPointToPlane()
    else:
        estimation = reg.TransformationEstimationPointToPoint(with_scaling=with_scaling)
    transform = np.asarray(init, dtype=np.float64)
    for distance in distances:
        result = reg.registration_icp(
            source,
            target,
            distance,
            transform,
            estimation,
            reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=max_iteration),
        )
        transform = np.asarray(result.transformation)
    return transform


def _rotation_between_deg(transform_a, transform_b) -> float:
    return rotation_angle_deg(decompose_similarity(transform_a)[1], decompose_similarity(transform_b)[1])


def _rivals(candidates, best, n_rivals):
    """The best-scoring plausible candidates that are other poses than ``best`` and each other (> 45 degrees apart)."""
    rivals = []
    for candidate in sorted(candidates, key=lambda candidate: candidate.score, reverse=True):
        if len(rivals) == n_rivals or not candidate.plausible:
            break
        if all(
            _rotation_between_deg(candidate.input_to_body, other.input_to_body) > _DISTINCT_POSE_DEG
            for other in [best, *rivals]
        ):
            rivals.append(candidate)
    return rivals


def _ambiguity(chosen, rival, inlier_distance) -> float:
    """How well ``rival`` fits compared with ``chosen`` (0: far worse, 1: as well), on the same points.

    On ``chosen``'s inliers (outliers are equally far from the surface in
    every pose and would even the scores out): ``chosen``'s mean-square
    distance over ``rival``'s truncated mean square ``mean(min(d, inlier)^2)``.
    """
    inliers = chosen.distances <= inlier_distance
    if not inliers.any():
        return float("nan")
    rival_mean_square = np.mean(np.minimum(rival.distances[inliers], inlier_distance) ** 2)
    return float(np.mean(chosen.distances[inliers] ** 2) / max(rival_mean_square, 1e-300))


def _dense_points(points, n_neighbours, distance_ratio, passes=3) -> np.ndarray:
    """Mask of points whose mean distance to their nearest neighbours is at most ``distance_ratio`` x the median.

    On a voxel-thinned cloud the surface is sampled about evenly, so stray
    points in the empty space around it stand out by their distance to their
    neighbours. The median is robust to them (open3d's statistical outlier
    removal thresholds on mean + k std, which a fifth of outliers inflates
    until it removes almost nothing). Repeated up to ``passes`` times: with
    many outliers (40 %) the first pass leaves some, which then stand alone.
    """
    from scipy.spatial import cKDTree

    kept = np.ones(len(points), dtype=bool)
    for _ in range(passes):
        index = np.flatnonzero(kept)
        if len(index) <= n_neighbours:
            break
        distances, _ = cKDTree(points[index]).query(points[index], n_neighbours + 1)
        mean_distance = distances[:, 1:].mean(axis=1)
        stray = mean_distance > distance_ratio * np.median(mean_distance)
        if not stray.any():
            break
        kept[index[stray]] = False
    return kept


class _Candidate:
    """A pose: its input-to-body transform, the distances (m) of some source points, and their scores.

    A pose whose scale strays more than ``_SCALE_TOLERANCE`` from the size
    estimate ``expected_scale`` is implausible and scores -1: scaled ICP can
    shrink a cloud that fits nowhere onto one spot of the surface, where
    every point then lies "on" it.
    """

    def __init__(self, input_to_body, distances_m, inlier_m, expected_scale):
        self.input_to_body = input_to_body
        self.distances = distances_m
        scale_ratio = np.cbrt(np.linalg.det(input_to_body[:3, :3])) / expected_scale
        self.plausible = bool(1.0 / _SCALE_TOLERANCE <= scale_ratio <= _SCALE_TOLERANCE)
        # Mean truncated-quadratic agreement: 1 on the surface, 0 at or beyond the inlier distance.
        self.score = float(np.mean(np.clip(1.0 - (distances_m / inlier_m) ** 2, 0.0, None))) if self.plausible else -1.0
        self.fitness, self.inlier_rmse_m = _fit_stats(distances_m, inlier_m)


def _fit_stats(distances, inlier_distance) -> tuple[float, float]:
    """(fitness, inlier RMSE) of point-to-surface distances."""
    inliers = distances <= inlier_distance
    fitness = float(inliers.mean()) if len(distances) else 0.0
    rmse = float(np.sqrt(np.mean(distances[inliers] ** 2))) if inliers.any() else float("inf")
    return fitness, rmse

# ---------------------------------------------------------------- the steps of the registration


@dataclass(frozen=True)
class _Settings:
    """What :func:`register_to_shape` was asked to do (its keyword arguments that steer the search and decide success)."""

    estimate_scale: bool
    global_search: bool
    init_transform: np.ndarray | None
    seed: int
    n_ransac: int
    ransac_max_iteration: int
    success_rms_rel: float
    success_fitness: float
    success_ambiguity: float


@dataclass(frozen=True)
class _Input:
    """The checked input: the mesh, the number of input points, and the finite ones (with their normals, or None)."""

    vertices_m: np.ndarray
    faces: np.ndarray
    n_points: int
    points: np.ndarray
    normals: np.ndarray | None


def _checked_input(points, normals, shape_vertices_m, shape_faces, settings: _Settings) -> _Input:
    """The input as arrays, its rows with a NaN dropped; ValueError if malformed, DataFailure if fewer than 30 points are left."""
    points = _as_points(points)
    vertices_m, faces = _as_mesh(shape_vertices_m, shape_faces)
    if normals is not None:
        normals = _as_points(normals, "normals")
        if len(normals) != len(points):
            raise ValueError(f"normals has {len(normals)} rows but points has {len(points)}")
    finite = np.all(np.isfinite(points), axis=1)
    if normals is not None:
        finite &= np.all(np.isfinite(normals), axis=1)
    points_in = points[finite]
    normals_in = None if normals is None else normals[finite]
    if len(points_in) < 30:
        raise DataFailure(f"need at least 30 finite points to register, got {len(points_in)}")
    if not settings.global_search and settings.init_transform is None:
        raise ValueError("global_search=False needs an init_transform")
    return _Input(vertices_m, faces, len(points), points_in, normals_in)


@dataclass(frozen=True)
class _Target:
    """The shape model as the target, in the body frame (metres).

    ``surface`` queries the exact mesh; ``length_m``, ``voxel_m`` and
    ``inlier_m`` are the body length, the voxel size and the inlier band.
    ``points`` and ``normals``: dense uniform samples of the surface with
    their facets' normals (the target of the final point-to-plane ICP);
    ``fine``: those thinned to half a voxel (the target of the scaled ICP),
    with centroid ``centre`` and RMS radius ``radius``.
    """

    vertices_m: np.ndarray
    faces: np.ndarray
    surface: SurfaceQuery
    length_m: float
    voxel_m: float
    inlier_m: float
    points: np.ndarray
    normals: np.ndarray
    fine: object
    centre: np.ndarray
    radius: float


def _sample_target(vertices_m, faces, voxel_size, inlier_distance_rel, rng) -> _Target:
    """The target: dense uniform samples of the surface with facet normals (drawn from ``rng``)."""
    length_m = body_length_m(vertices_m, faces)
    voxel_m = float(voxel_size) if voxel_size is not None else VOXEL_SIZE_REL * length_m
    inlier_m = inlier_distance_rel * length_m
    surface = SurfaceQuery(vertices_m, faces)
    _, facet_normals, areas = facet_geometry(vertices_m, faces)
    n_dense = int(np.clip(areas.sum() / (0.25 * voxel_m) ** 2, 20_000, 200_000))
    target_points, target_facets = sample_surface(vertices_m, faces, n_dense, rng)
    target_normals = facet_normals[target_facets]
    target_fine = _point_cloud(target_points, target_normals).voxel_down_sample(0.5 * voxel_m)
    target_centre, target_radius = _centre_and_rms_radius(np.asarray(target_fine.points))
    return _Target(
        vertices_m, faces, surface, length_m, voxel_m, inlier_m, target_points, target_normals, target_fine, target_centre, target_radius
    )


@dataclass(frozen=True)
class _Source:
    """The input cloud made ready to register.

    The "rough" frame: the finite input points less their median
    ``rough_centre``, times ``rough_scale`` (the body's median radius over
    theirs, or 1 when the scale is known). ``fine``: the cloud in that frame
    thinned to half a voxel, stray points removed, with normals (given, or
    estimated away from the centroid); ``centre`` and ``radius`` its
    centroid and RMS radius.
    """

    rough_centre: np.ndarray
    rough_scale: float
    fine: object
    centre: np.ndarray
    radius: float


def _prepare_source(cloud: _Input, target: _Target, estimate_scale, outlier_neighbours, outlier_distance_ratio) -> _Source:
    """The source roughly brought to the body's size (median radius), then thinned and cleaned of outliers."""
    import open3d as o3d

    points_in, normals_in, voxel_m = cloud.points, cloud.normals, target.voxel_m
    rough_centre = np.median(points_in, axis=0)
    rough_radius = float(np.median(np.linalg.norm(points_in - rough_centre, axis=1)))
    target_median_radius = float(np.median(np.linalg.norm(target.points - target.centre, axis=1)))
    if not rough_radius > 0:
        raise DataFailure("the points have no extent (all at one place)")
    if estimate_scale:
        rough_scale = target_median_radius / rough_radius
    else:
        rough_scale = 1.0
    source_rough = _point_cloud((points_in - rough_centre) * rough_scale, normals_in)
    source_fine = source_rough.voxel_down_sample(0.5 * voxel_m)
    source_fine = source_fine.select_by_index(
        np.flatnonzero(_dense_points(np.asarray(source_fine.points), outlier_neighbours, outlier_distance_ratio))
    )
    if len(source_fine.points) < 30:
        raise DataFailure(f"fewer than 30 points left after thinning and outlier removal ({len(source_fine.points)})")
    source_centre, source_radius = _centre_and_rms_radius(np.asarray(source_fine.points))
    if normals_in is None:
        # Orient estimated normals away from the centroid (right for most of a
        # star-shaped body such as Itokawa).
        source_fine.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel_m, max_nn=30))
        source_fine.orient_normals_towards_camera_location(source_centre)
        source_fine.normals = o3d.utility.Vector3dVector(-np.asarray(source_fine.normals))
    return _Source(rough_centre, rough_scale, source_fine, source_centre, source_radius)


@dataclass(frozen=True)
class _Frames:
    """The frames of the search and the similarities between them.

    Normalised frames: target ``y' = (y - c_t) / r_t`` (``to_target_norm``
    from the body frame, ``from_target_norm`` back); source ``x' = f
    (x_rough - c_s) / r_s`` for a size factor ``f`` (:meth:`rough_to_norm`).
    ``rough_to_input`` and ``input_to_rough`` lead between the input frame
    and the source's rough frame. ``expected_scale``: the input-to-body
    scale the size estimate gives (or the fixed one).
    """

    size_ratio: float
    expected_scale: float
    target_radius: float
    source_centre: np.ndarray
    to_target_norm: np.ndarray
    from_target_norm: np.ndarray
    rough_to_input: np.ndarray
    input_to_rough: np.ndarray

    def rough_to_norm(self, factor) -> np.ndarray:
        """The source's rough frame to its normalised frame, re-sized by ``factor``."""
        scale = factor * self.size_ratio / self.target_radius
        return similarity_transform(scale, np.eye(3), -scale * self.source_centre)


def _frames(target: _Target, source: _Source, settings: _Settings) -> _Frames:
    size_ratio = target.radius / source.radius if settings.estimate_scale else 1.0
    if settings.estimate_scale or settings.init_transform is None:
        expected_scale = source.rough_scale * size_ratio
    else:
        expected_scale = decompose_similarity(settings.init_transform)[0]
    to_target_norm = similarity_transform(1.0 / target.radius, np.eye(3), -target.centre / target.radius)
    from_target_norm = np.linalg.inv(to_target_norm)
    rough_to_input = similarity_transform(1.0 / source.rough_scale, np.eye(3), source.rough_centre)
    input_to_rough = np.linalg.inv(rough_to_input)
    return _Frames(
        size_ratio, expected_scale, target.radius, source.centre, to_target_norm, from_target_norm, rough_to_input, input_to_rough
    )


@dataclass(frozen=True)
class _NormalisedTarget:
    """The target in its normalised frame, where the global search runs.

    ``voxel``: the voxel size in that frame; ``coarse``: the target thinned
    to it, with FPFH ``features`` and principal ``axes``; ``flips``: the
    rotations that map those axes onto themselves; ``surface``: the exact
    mesh in that frame.
    """

    voxel: float
    coarse: object
    features: object
    axes: np.ndarray
    flips: list
    surface: SurfaceQuery


def _normalised_target(target: _Target) -> _NormalisedTarget:
    voxel = target.voxel_m / target.radius
    target_norm = _point_cloud(
        (np.asarray(target.fine.points) - target.centre) / target.radius, np.asarray(target.fine.normals)
    )
    target_coarse = target_norm.voxel_down_sample(voxel)
    target_features = _features(target_coarse, voxel)
    target_axes = _axes_of(np.asarray(target_coarse.points))
    flips = [target_axes @ np.diag(signs) @ target_axes.T for signs in _AXIS_FLIPS]
    norm_vertices = (target.vertices_m - target.centre) / target.radius
    norm_surface = SurfaceQuery(norm_vertices, target.faces)
    return _NormalisedTarget(voxel, target_coarse, target_features, target_axes, flips, norm_surface)


# ---------------------------------------------------------------- stage 1: candidates


def _ransac_starts(source_coarse, source_features, norm_target: _NormalisedTarget, settings: _Settings) -> list:
    """Feature matching: a RANSAC pose per run (seeded), each also turned by the principal-axis flips."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    voxel = norm_target.voxel
    starts = []
    for attempt in range(settings.n_ransac):
        o3d.utility.random.seed(int(settings.seed) * 1000 + attempt)
        ransac = reg.registration_ransac_based_on_feature_matching(
            source_coarse,
            norm_target.coarse,
            source_features,
            norm_target.features,
            False,
            1.5 * voxel,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel),
            ],
            reg.RANSACConvergenceCriteria(settings.ransac_max_iteration, 0.999),
        )
        starts += [similarity_transform(1.0, flip, np.zeros(3)) @ ransac.transformation for flip in norm_target.flips]
    return starts


def _principal_axis_starts(source_coarse, norm_target: _NormalisedTarget) -> list:
    """The source's principal axes onto the target's, and that turned by each flip."""
    target_axes = norm_target.axes
    source_coarse_points = np.asarray(source_coarse.points)
    source_axes = _axes_of(source_coarse_points)
    source_mean = source_coarse_points.mean(axis=0)
    pca = similarity_transform(1.0, target_axes @ source_axes.T, -target_axes @ source_axes.T @ source_mean)
    return [similarity_transform(1.0, flip, np.zeros(3)) @ pca for flip in norm_target.flips]


def _starts(source_coarse, rough_to_norm, norm_target: _NormalisedTarget, frames: _Frames, settings: _Settings) -> list:
    """The coarse alignments (normalised source to normalised target) at one size: RANSAC, principal axes, the given guess."""
    starts = []
    if settings.global_search:
        source_features = _features(source_coarse, norm_target.voxel)
        starts += _ransac_starts(source_coarse, source_features, norm_target, settings)
        starts += _principal_axis_starts(source_coarse, norm_target)
    if settings.init_transform is not None:
        # input -> body  ==>  normalised source -> normalised target.
        norm_to_input = frames.rough_to_input @ np.linalg.inv(rough_to_norm)
        starts.append(frames.to_target_norm @ np.asarray(settings.init_transform, dtype=np.float64) @ norm_to_input)
    return starts


def _polished_candidate(
    start_transform, subset_norm, rough_to_norm, norm_target: _NormalisedTarget, frames: _Frames, target: _Target, settings: _Settings
) -> _Candidate:
    """A start polished by a short ICP on the coarse target, and scored on ``subset_norm`` against the exact surface."""
    voxel = norm_target.voxel
    transform = _icp(
        _point_cloud(subset_norm),
        norm_target.coarse,
        start_transform,
        [3.0 * voxel, 1.5 * voxel],
        with_scaling=settings.estimate_scale,
        max_iteration=20,
    )
    distances_m = norm_target.surface.distance(transform_points(transform, subset_norm)) * frames.target_radius
    input_to_body = frames.from_target_norm @ transform @ rough_to_norm @ frames.input_to_rough
    return _Candidate(input_to_body, distances_m, target.inlier_m, frames.expected_scale)


def _global_search(
    source: _Source, target: _Target, norm_target: _NormalisedTarget, frames: _Frames, settings: _Settings, rng
) -> tuple[list, _Candidate]:
    """Stage 1: the candidates over the size hypotheses (until one passes), and the best of them.

    Every candidate is polished and scored on the same random subset of the
    source, so that scores compare across size hypotheses.
    """
    subset_rough = np.asarray(source.fine.points)[
        np.sort(rng.permutation(len(source.fine.points))[:_CANDIDATE_POINTS])
    ]
    factors = _RESIZE_FACTORS if (settings.estimate_scale and settings.global_search) else (1.0,)
    candidates = []
    for factor in factors:
        rough_to_norm = frames.rough_to_norm(factor)
        source_norm = _point_cloud(
            transform_points(rough_to_norm, np.asarray(source.fine.points)), np.asarray(source.fine.normals)
        )
        source_coarse = source_norm.voxel_down_sample(norm_target.voxel)
        subset_norm = transform_points(rough_to_norm, subset_rough)
        for start_transform in _starts(source_coarse, rough_to_norm, norm_target, frames, settings):
            candidates.append(_polished_candidate(start_transform, subset_norm, rough_to_norm, norm_target, frames, target, settings))
        best = max(candidates, key=lambda candidate: candidate.score)
        logger.debug("size factor %.2f: best score %.3f fitness %.3f", factor, best.score, best.fitness)
        if (
            best.plausible
            and best.fitness > settings.success_fitness
            and best.inlier_rmse_m < settings.success_rms_rel * target.length_m
        ):
            break
    return candidates, best


# ---------------------------------------------------------------- stage 2: ICP in the body frame, and the choice


@dataclass(frozen=True)
class _BodyFrameIcp:
    """The final ICP in the body frame, and the scores of its poses against the exact surface.

    ``dense``: the target's dense samples with their normals (the default
    target of the point-to-plane step).
    """

    target: _Target
    dense: object
    estimate_scale: bool
    expected_scale: float

    def refine(self, input_to_body, source, target_for_planes=None, max_iteration=30) -> np.ndarray:
        """Scaled point-to-point ICP against the thinned target, then rigid point-to-plane ICP."""
        voxel_m = self.target.voxel_m
        transform = _icp(
            source,
            self.target.fine,
            input_to_body,
            [2.0 * voxel_m, 1.0 * voxel_m],
            with_scaling=self.estimate_scale,
            max_iteration=max_iteration,
        )
        return _icp(
            source,
            self.dense if target_for_planes is None else target_for_planes,
            transform,
            [1.0 * voxel_m, 0.5 * voxel_m],
            with_scaling=False,
            point_to_plane=True,
            max_iteration=max_iteration,
        )

    def scored(self, input_to_body, points) -> _Candidate:
        distances_m = self.target.surface.distance(transform_points(input_to_body, points))
        return _Candidate(input_to_body, distances_m, self.target.inlier_m, self.expected_scale)


def _choose_against_rivals(chosen: _Candidate, best, candidates, source_body, icp: _BodyFrameIcp, rng) -> tuple[_Candidate, float]:
    """The chosen pose (``chosen``, or a rival that fits better) and its ambiguity (NaN when there is no rival).

    The best other poses of the global search are refined the same way as
    the chosen one (their scores from the short ICP on a coarse target are
    not converged enough to compare with the chosen pose's), on a subset of
    the source to save time. A rival that ICP brings into the chosen pose is
    no rival; one that ends up fitting better is chosen instead.
    """
    rivals = _rivals(candidates, best, _RIVALS_REFINED)
    if not rivals:
        return chosen, float("nan")
    ambiguity = 0.0
    source_body_points = np.asarray(source_body.points)
    subset_points = source_body_points[np.sort(rng.permutation(len(source_body_points))[:_RIVAL_POINTS])]
    subset = _point_cloud(subset_points)
    chosen_on_subset = icp.scored(chosen.input_to_body, subset_points)
    for rival in rivals:
        rival = icp.scored(icp.refine(rival.input_to_body, subset, icp.target.fine, 20), subset_points)
        same_pose = _rotation_between_deg(rival.input_to_body, chosen.input_to_body) <= _DISTINCT_POSE_DEG
        if same_pose or not rival.plausible:
            continue
        if rival.score > chosen_on_subset.score:
            ambiguity = _ambiguity(rival, chosen_on_subset, icp.target.inlier_m)
            chosen = icp.scored(icp.refine(rival.input_to_body, source_body), source_body_points)
        else:
            ambiguity = _ambiguity(chosen_on_subset, rival, icp.target.inlier_m)
        break
    return chosen, ambiguity


def _registration_result(
    chosen: _Candidate,
    ambiguity: float,
    cloud: _Input,
    n_points_registered: int,
    n_candidates: int,
    target: _Target,
    settings: _Settings,
    seconds_global: float,
    seconds_icp: float,
) -> RegistrationResult:
    """The chosen pose scored against the exact surface, decided (``success``) and logged."""
    length_m = target.length_m
    transform = chosen.input_to_body
    fitness, inlier_rmse_m = chosen.fitness, chosen.inlier_rmse_m
    inlier_fraction_all = float(np.mean(target.surface.distance(transform_points(transform, cloud.points)) <= target.inlier_m))
    rms_distance_rel = inlier_rmse_m / length_m
    scale, rotation, translation = decompose_similarity(transform)
    unambiguous = not ambiguity >= settings.success_ambiguity  # NaN (no other pose tried) passes
    success = bool(
        rms_distance_rel < settings.success_rms_rel and fitness > settings.success_fitness and unambiguous and chosen.plausible
    )
    logger.info(
        "registration %s: scale %.6g, fitness %.3f, inlier RMS %.3g m (%.3g %% of %.1f m), ambiguity %.3f, "
        "%d candidates, %.2f s global + %.2f s ICP",
        "succeeded" if success else "FAILED",
        scale,
        fitness,
        inlier_rmse_m,
        100 * rms_distance_rel,
        length_m,
        ambiguity,
        n_candidates,
        seconds_global,
        seconds_icp,
    )
    return RegistrationResult(
        transform=transform,
        scale=scale,
        rotation=rotation,
        translation_m=translation,
        success=success,
        fitness=fitness,
        inlier_rmse_m=inlier_rmse_m,
        rms_distance_rel=rms_distance_rel,
        inlier_fraction_all=inlier_fraction_all,
        body_length_m=length_m,
        inlier_distance_m=target.inlier_m,
        voxel_size_m=target.voxel_m,
        seconds_global=seconds_global,
        seconds_icp=seconds_icp,
        n_points_input=cloud.n_points,
        n_points_registered=n_points_registered,
        n_candidates=n_candidates,
        ambiguity=ambiguity,
        success_rms_rel=settings.success_rms_rel,
        success_fitness=settings.success_fitness,
        success_ambiguity=settings.success_ambiguity,
        plausible_scale=bool(chosen.plausible),
    )


# ---------------------------------------------------------------- registration


def register_to_shape(
    points,
    normals,
    shape_vertices_m,
    shape_faces,
    *,
    estimate_scale: bool = True,
    voxel_size=None,
    seed: int = 0,
    init_transform=None,
    global_search: bool = True,
    n_ransac: int = 1,
    ransac_max_iteration: int = 30_000,
    inlier_distance_rel: float = INLIER_DISTANCE_REL,
    success_rms_rel: float = SUCCESS_RMS_REL,
    success_fitness: float = SUCCESS_FITNESS,
    success_ambiguity: float = SUCCESS_AMBIGUITY,
    outlier_neighbours: int = 12,
    outlier_distance_ratio: float = 2.0,
) -> RegistrationResult:
    """Find the similarity that puts a reconstructed cloud onto the shape model, and score it.

    Parameters
    ----------
    points : (N, 3) reconstructed points in their own frame (any unit; NaN rows are ignored).
    normals : (N, 3) their outward normals in the same frame, or None to
        estimate them (oriented away from the cloud's centroid).
    shape_vertices_m, shape_faces : the reference mesh in the body frame
        (metres, 0-based faces; unused vertices allowed).
    estimate_scale : True for a cloud of unknown scale (SfM without priors);
        False when the cloud is already in metres: the scale is then held at
        1 (or at the scale of ``init_transform`` when only that is refined).
    voxel_size : metres in the body frame for features and ICP; default
        ``VOXEL_SIZE_REL`` of the body length (11 m for Itokawa). The source
        is brought to the body's size before it is thinned, so one voxel
        size serves both clouds.
    seed : seeds the surface sampling and open3d's RANSAC.
    init_transform : optional 4x4 input-to-body similarity guess (e.g. from
        position priors); it joins the candidates of the global search, or
        is the only start when ``global_search`` is False.
    n_ransac : RANSAC runs (different seeds) per size hypothesis.
    inlier_distance_rel, success_rms_rel, success_fitness, success_ambiguity :
        the inlier band and the success thresholds (the first two as
        fractions of the body length); defaults and reasons at the top of
        this module.
    outlier_neighbours, outlier_distance_ratio : outlier removal applied to
        the thinned source before registration: a point is dropped when its
        mean distance to its ``outlier_neighbours`` nearest neighbours exceeds
        ``outlier_distance_ratio`` times the median of that over the cloud.

    Returns a :class:`RegistrationResult`. Raises ValueError for malformed
    input, :class:`DataFailure` for fewer than 30 usable points.
    """
    import open3d as o3d

    # One thread for open3d, process-wide: its point-to-plane ICP sums over the points on TBB threads
    # in the order they finish, so with more the registration differs in the last bits from run to run
    # (and the rules that register have one thread).
    o3d.utility.set_max_threads(1)
    start = time.perf_counter()
    settings = _Settings(
        estimate_scale, global_search, init_transform, seed, n_ransac, ransac_max_iteration,
        success_rms_rel, success_fitness, success_ambiguity,
    )
    cloud = _checked_input(points, normals, shape_vertices_m, shape_faces, settings)
    rng = np.random.default_rng(seed)
    target = _sample_target(cloud.vertices_m, cloud.faces, voxel_size, inlier_distance_rel, rng)
    source = _prepare_source(cloud, target, estimate_scale, outlier_neighbours, outlier_distance_ratio)
    frames = _frames(target, source, settings)
    norm_target = _normalised_target(target)

    # --- stage 1: global search over size hypotheses, RANSAC and PCA candidates.
    candidates, best = _global_search(source, target, norm_target, frames, settings, rng)
    seconds_global = time.perf_counter() - start

    # --- stage 2: ICP in the body frame: scaled point-to-point, then point-to-plane.
    start = time.perf_counter()
    source_body = _point_cloud(transform_points(frames.rough_to_input, np.asarray(source.fine.points)))
    icp = _BodyFrameIcp(target, _point_cloud(target.points, target.normals), estimate_scale, frames.expected_scale)
    chosen = icp.scored(icp.refine(best.input_to_body, source_body), np.asarray(source_body.points))
    # Ambiguity: the best other poses of the global search, refined the same way.
    chosen, ambiguity = _choose_against_rivals(chosen, best, candidates, source_body, icp, rng)
    seconds_icp = time.perf_counter() - start

    return _registration_result(
        chosen, ambiguity, cloud, len(source_body.points), len(candidates), target, settings, seconds_global, seconds_icp
    )
