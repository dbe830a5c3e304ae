"""Sparse reconstruction of one rendered set with pycolmap, with navigation position priors.

Where it sits: after ``render`` and before a dense cloud or brightness sampling
through *reconstructed* cameras. The ground-truth path of the workflow uses the
known poses and the shape model; this module instead recovers the cameras and a
sparse point cloud from the set's own images, as a mission would, with the
spacecraft's navigation solution (camera positions in the body frame, a few
metres accurate) as priors in bundle adjustment.

Steps (:func:`reconstruct_images`; steps 1 and 2 are :func:`match_images`,
which the workflow runs once per set, 3 to 5 :func:`map_matches`, once per
prior setting):

1. **Images.** The linear float images are mapped to 8-bit grayscale PNGs with
   one monotone tone curve for the whole set (:func:`tone_map`), so a surface
   patch keeps its grey level from image to image.
2. **Features and matches.** COLMAP SIFT on the CPU; one shared ``PINHOLE``
   camera built from the known intrinsics; exhaustive matching (36 images,
   630 pairs: the cheapest way to close the loop, the body turns 10 degrees per
   image and comes back to the start) with geometric verification.
3. **Incremental mapping** (``pycolmap.incremental_mapping``). With priors on,
   the pose priors are in the database and the mapper's global bundle
   adjustments are pose-prior bundle adjustments, so the model is built in
   the body frame at metric scale; with priors off it lives in an arbitrary
   similarity frame.
4. **A final bundle adjustment** over the largest model with the weights of
   the stated accuracies (:func:`bundle_adjust`), plain least squares
   (no robust loss), intrinsics held or refined as asked.
5. **Report** (:class:`ReconstructionReport`): images registered, points,
   reprojection RMS, camera-position residuals against the priors and the
   over-fitting diagnostic. Nothing here reads the true cameras: the priors
   come with the images (the mission's navigation file), and the cameras
   are scored against the truth by the scoring stage
   (``evaluation.quality.camera_errors``).

Weighting. Photogrammetry packages such as Metashape minimise
``sum (r_px / sigma_tie_px)^2 + sum |c - c_prior|^2 / sigma_cam_m^2`` (tie
point accuracy in pixels, camera accuracy in metres). COLMAP's reprojection
residuals are in pixels with unit weight and its position-prior residuals are
whitened by the prior covariance, so multiplying the whole cost by
``sigma_tie_px^2`` gives exactly COLMAP's cost with the prior covariance
``(sigma_cam_m / sigma_tie_px)^2 * I``: that is what is written to the
database and given to the final adjustment.

Over-fitting diagnostic. ``cam_pos_rms_m`` is the RMS over the registered
images of the 3-D distance between the adjusted camera centre and its prior
(Metashape's "total error"). If the tie points alone fixed the shape of the
camera path, the priors would only fix the 7 similarity degrees of freedom and
the residuals would be the navigation noise itself, with expected RMS
``sigma * sqrt(3 - 7 / n)`` for n images (``cam_pos_rms_expected_m``). Priors
that dominate pull the cameras onto themselves and the RMS falls below that.
``prior_overfit`` is raised when ``cam_pos_rms_m < overfit_ratio *
cam_pos_rms_expected_m``, ``overfit_ratio = 0.5`` by default. Why 0.5: if the
priors alone set one of the three axes of every camera the ratio is about
0.82, two axes 0.58, all three 0; below 0.5 the priors set the cameras in
every direction, which is "clearly below the stated accuracy".

Tone curve: ``linear`` (the set's 99.9th percentile of lit pixels -> 255),
chosen by measurement on ``light10_albedo0.7_k0.8``, priors off, default SIFT:

=========  =================  ==========  ======  ============  ==================
curve      keypoints / image  registered  points  reproj (px)   cameras vs truth
=========  =================  ==========  ======  ============  ==================
linear     520                36 / 36     1520    0.45          24.3 m, 0.33 deg
sqrt       317                15 / 36     402     0.49          36 m (15 images)
log        94                 no model
=========  =================  ==========  ======  ============  ==================

The brief expected a curve that lifts the dark terminator, but at phase 0 and
10 degrees there is almost no terminator: Itokawa's texture lies in the
bright half (lit pixels 0.25-0.70 of a 0.70 maximum), and compressive curves
flatten it. On ``light0_albedo0.7_k0.8`` sqrt registered 13 of 36 images,
linear all 36. Also tried and dropped: set-wide histogram equalisation of the
lit pixels (2119 points, but cameras 27 m to 115 m from the truth depending on
the seed) and a square curve (2026 points, 32.5 m).

Feature settings: COLMAP's defaults gave the best cameras, every change gave
more points but worse poses (same set, priors off; points, reprojection RMS,
camera RMS vs truth): peak threshold 0.002: 1946, 0.46 px, 28.5 m; upright:
1932, 0.62 px, 41.9 m; domain-size pooling: 1745, 0.58 px, 68 m; guided
matching: 1977, 0.67 px, 45.9 m. :class:`FeatureOptions` keeps the switches.
The mapper's registration thresholds are lowered (15 inliers, 10 %; config
keys ``reconstruction.min_pose_inliers`` and ``min_pose_inlier_ratio``): the
k = 0.7 sets give ~400 features per image and COLMAP's 30 inliers left only
16-20 of their 36 images registered.

Measured (2-core machine, fixed intrinsics, seed 0, 36 images of 512 px,
camera 5 km away, 8 degree field of view; "vs truth" is after a similarity
alignment when priors are off):

=================  =========  ======  ======  ======  ===========  =====  ========  ========  ====
set                sigma (m)  images  points  reproj  cam-prior    ratio  overfit   vs truth  s
=================  =========  ======  ======  ======  ===========  =====  ========  ========  ====
light10 a0.7 k0.8  1          36      1523    0.445   0.096 m      0.057  yes       1.64 m    15
light10 a0.7 k0.8  off        36      1520    0.447                                 24.3 m    18
light0 a0.7 k0.8   1          36      1377    0.448   0.136 m      0.081  yes       1.65 m    20
light0 a0.7 k0.8   off        36      1369    0.451                                 38.4 m    20
light10, sweep     10         36      1526    0.442   8.5 m        0.51   no        12.1 m    18
light10, sweep     30         36      1524    0.449   39 m         0.78   no        23.1 m    22
light10, sweep     100        36      1525    0.437   154 m        0.92   no        53.6 m    16
=================  =========  ======  ======  ======  ===========  =====  ========  ========  ====

(tie-point accuracy 1 px; the priors' own error is 1.66 sigma RMS; camera
rotation errors 0.14 deg with 1 m priors, 0.33 / 0.53 deg without; with 1 m
priors the sparse points lie a median 4.5 m / 3.2 m from the shape model's
surface, 90 % within 8.6 m / 6.9 m, with single strays up to 1.4 km: filter
before use.) The
diagnostic reads this geometry correctly: from 5 km with an 8 degree field of
view the tie points place a camera only to some 20-40 m (mostly across the line
of sight: a view-direction error of 0.2-0.3 degrees changes the image by
hundredths of a pixel), so 1 m navigation priors dominate and the cameras sit
on them (ratio 0.06, flagged; the adjusted cameras are no better than the
navigation, 1.64 m against 1.66 m). With a stated tie-point accuracy of 0.3 px
(the measured per-axis scatter) the ratio is 0.49, still flagged. Priors of
10 m or more leave the tie points in charge (not flagged), and the fused
cameras beat both sources (12.1 m against 16.6 m navigation and 24 m images).

``intrinsics="refine"`` frees the focal lengths in the final adjustment only.
The field of view is too narrow to separate focal length from distance and
size: with 1 m priors it converged to f = 3900 px (true 3561 px) at unchanged
reprojection RMS, so the model came out about 9 % too small; without priors to
4690 px. Keep ``"fixed"`` unless the intrinsics are really in doubt.

Frames follow :mod:`asteroid_photometry`: OpenCV/COLMAP camera frame, metres,
pixel corner at (0, 0) (COLMAP's SIFT keypoints use the same convention), and
``body_to_camera`` is COLMAP's ``cam_from_world`` when the world is the body
frame.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from asteroid_photometry.core import files
from asteroid_photometry.world.cameras import camera_centres_body, Intrinsics

log = logging.getLogger(__name__)

#: Robust maximum of a set: this percentile of the lit (positive) pixels of all images.
REFERENCE_PERCENTILE = 99.9

#: Tone curves from ``x`` (linear brightness over the set's robust maximum, clipped to [0, 1]) to [0, 1].
TONE_CURVES = {
    "linear": lambda x: x,
    "sqrt": np.sqrt,
    "log": lambda x: np.log1p(255.0 * x) / np.log1p(255.0),
}

DEFAULT_TONE_CURVE = "linear"

#: Over-fitting flag: residual RMS below this fraction of the RMS expected from navigation noise alone.
DEFAULT_OVERFIT_RATIO = 0.5

#: A model of fewer registered images is no reconstruction (``DataFailure``): it cannot be aligned or scored.
MIN_REGISTERED_IMAGES = 3


# --------------------------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------------------------


def reference_brightness(images) -> float:
    """The set's robust maximum: the ``REFERENCE_PERCENTILE`` of its positive pixels (1 if none)."""
    lit = np.concatenate([np.asarray(image, dtype=float).ravel() for image in images])
    lit = lit[lit > 0]
    if lit.size == 0:
        return 1.0
    return float(np.percentile(lit, REFERENCE_PERCENTILE))


def tone_map(image: np.ndarray, reference: float, curve: str = DEFAULT_TONE_CURVE) -> np.ndarray:
    """An 8-bit grayscale image (uint8, same shape) of a linear float image.

    ``reference`` is the set's robust maximum (:func:`reference_brightness`),
    the same for every image of a set so that a surface patch keeps its grey
    level across images; brightness at or above it saturates at 255. The
    curve is monotone (non-decreasing) in the linear brightness.
    """
    if curve not in TONE_CURVES:
        raise ValueError(f"unknown tone curve {curve!r} (known: {', '.join(TONE_CURVES)})")
    if not reference > 0:
        raise ValueError(f"reference brightness must be positive, got {reference}")
    scaled = np.clip(np.nan_to_num(np.asarray(image, dtype=float), nan=0.0) / reference, 0.0, 1.0)
    return np.round(255.0 * TONE_CURVES[curve](scaled)).astype(np.uint8)


def write_images(images, names, image_dir, curve: str = DEFAULT_TONE_CURVE) -> float:
    """Tone-map a set and write one 8-bit PNG per image; returns the reference brightness used.

    Written with pycolmap's own bitmap writer: PIL's PNG encoder aborts in a
    process that has loaded pycolmap (two zlib builds).
    """
    import pycolmap

    image_dir = Path(image_dir)
    image_dir.mkdir(parents=True, exist_ok=True)
    reference = reference_brightness(images)
    for image, name in zip(images, names):
        if not pycolmap.Bitmap.from_array(tone_map(image, reference, curve)).write(image_dir / name):
            raise OSError(f"cannot write {image_dir / name}")
    return reference


# --------------------------------------------------------------------------------------------
# Navigation priors and alignment
# --------------------------------------------------------------------------------------------


def prior_covariance(camera_position_sigma_m: float, tie_point_sigma_px: float) -> np.ndarray:
    """The 3x3 position covariance that gives COLMAP's unit-weight pixel residuals the stated accuracies (module docstring)."""
    if not camera_position_sigma_m > 0 or not tie_point_sigma_px > 0:
        raise ValueError(
            f"accuracies must be positive: camera_position_sigma_m={camera_position_sigma_m}, tie_point_sigma_px={tie_point_sigma_px}"
        )
    return (camera_position_sigma_m / tie_point_sigma_px) ** 2 * np.eye(3)


def similarity_alignment(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama 1991) with ``target ~ scale * rotation @ source + translation``.

    Returns ``(scale, rotation (3, 3), translation (3,))``; needs 3 or more non-collinear points.
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3 or len(source) < 3:
        raise ValueError(f"need two (n >= 3, 3) arrays of corresponding points, got {source.shape} and {target.shape}")
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    source_centred, target_centred = source - source_mean, target - target_mean
    covariance = target_centred.T @ source_centred / len(source)
    u, singular_values, vt = np.linalg.svd(covariance)
    reflection = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        reflection[2, 2] = -1.0
    rotation = u @ reflection @ vt
    source_variance = (source_centred**2).sum() / len(source)
    scale = float(np.trace(np.diag(singular_values) @ reflection) / source_variance)
    translation = target_mean - scale * rotation @ source_mean
    return scale, rotation, translation


def rms(vectors: np.ndarray) -> float:
    """Root mean square of the Euclidean norms of (n, d) vectors."""
    vectors = np.asarray(vectors, dtype=float)
    return float(np.sqrt(np.mean(np.sum(vectors**2, axis=-1)))) if len(vectors) else float("nan")


# --------------------------------------------------------------------------------------------
# Reading a pycolmap model into arrays
# --------------------------------------------------------------------------------------------


def pose_matrix(rigid) -> np.ndarray:
    """A 4x4 matrix of a pycolmap ``Rigid3d`` (``cam_from_world`` is our ``body_to_camera`` when the world is the body frame)."""
    matrix = np.eye(4)
    matrix[:3, :] = rigid.matrix()
    return matrix


@dataclass
class Observations:
    """Every observation of a 3-D point in a model, as flat arrays (one row per observation)."""

    point3d_id: np.ndarray  # (m,) int64, COLMAP point3D ids
    image_id: np.ndarray  # (m,) int64, COLMAP image ids
    uv: np.ndarray  # (m, 2) float64, pixels, corner of the top-left pixel at (0, 0)


def model_observations(reconstruction) -> Observations:
    """All (point, image, pixel) observations of the registered images of a pycolmap model."""
    point_ids, image_ids, uvs = [], [], []
    for image_id in sorted(reconstruction.reg_image_ids()):
        image = reconstruction.image(image_id)
        points2d = image.get_observation_points2D()
        point_ids.append(np.array([p.point3D_id for p in points2d], dtype=np.int64))
        uvs.append(np.array([p.xy for p in points2d], dtype=float).reshape(-1, 2))
        image_ids.append(np.full(len(points2d), image_id, dtype=np.int64))
    if not point_ids:
        return Observations(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))
    return Observations(np.concatenate(point_ids), np.concatenate(image_ids), np.concatenate(uvs))


def reprojection_residuals(reconstruction, observations: Observations | None = None) -> np.ndarray:
    """Observed minus projected pixel position of every observation, (m, 2) pixels."""
    observations = model_observations(reconstruction) if observations is None else observations
    residuals = np.zeros_like(observations.uv)
    xyz = {point_id: reconstruction.point3D(point_id).xyz for point_id in np.unique(observations.point3d_id)}
    for image_id in np.unique(observations.image_id):
        image = reconstruction.image(int(image_id))
        rows = np.flatnonzero(observations.image_id == image_id)
        points_world = np.array([xyz[point_id] for point_id in observations.point3d_id[rows]])
        pose = pose_matrix(image.cam_from_world())
        points_cam = points_world @ pose[:3, :3].T + pose[:3, 3]
        projected = image.camera.img_from_cam(points_cam, check_cheirality=False)
        residuals[rows] = observations.uv[rows] - projected
    return residuals


# --------------------------------------------------------------------------------------------
# Bundle adjustment with position priors
# --------------------------------------------------------------------------------------------


def make_pose_priors(reconstruction, prior_positions: dict, covariance: np.ndarray) -> list:
    """pycolmap ``PosePrior`` objects (Cartesian, body frame) for the images of a model.

    ``prior_positions`` maps COLMAP image ids to camera centres (metres).
    """
    import pycolmap

    priors = []
    for image_id, position in prior_positions.items():
        if not reconstruction.exists_image(int(image_id)):
            continue
        priors.append(
            pycolmap.PosePrior(
                corr_data_id=reconstruction.image(int(image_id)).data_id,
                position=np.asarray(position, dtype=float),
                position_covariance=np.asarray(covariance, dtype=float),
                coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
            )
        )
    return priors


def bundle_adjust(
    reconstruction,
    prior_positions: dict | None = None,
    *,
    camera_position_sigma_m: float = 1.0,
    tie_point_sigma_px: float = 1.0,
    refine_intrinsics: bool = False,
    max_num_iterations: int = 200,
    num_threads: int = -1,
    seed: int = 0,
):
    """Global bundle adjustment of a pycolmap model in place; returns pycolmap's summary.

    With ``prior_positions`` (COLMAP image id -> camera centre in metres, the
    target frame), a pose-prior adjustment weighted by the stated accuracies
    (module docstring): pycolmap first aligns the model to the priors with a
    RANSAC similarity, so the result is in the priors' frame whatever frame it
    started in. Without, a plain adjustment with the gauge fixed on two
    cameras, so the model keeps its frame. Intrinsics are held unless
    ``refine_intrinsics`` (focal lengths only; the principal point is left
    alone, it trades off against the pointing of a narrow-field camera).
    Plain least squares: outliers were removed by the mapper.
    """
    import pycolmap

    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = bool(refine_intrinsics)
    options.refine_principal_point = False
    options.refine_extra_params = False
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.TRIVIAL
    options.ceres.solver_options.max_num_iterations = int(max_num_iterations)
    options.ceres.solver_options.function_tolerance = 1e-10
    options.ceres.solver_options.gradient_tolerance = 1e-10
    options.ceres.solver_options.parameter_tolerance = 1e-10
    options.ceres.solver_options.num_threads = int(num_threads)

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in reconstruction.reg_image_ids():
        config.add_image(image_id)
    if not refine_intrinsics:
        for camera_id in reconstruction.cameras:
            config.set_constant_cam_intrinsics(camera_id)

    if prior_positions:
        prior_options = pycolmap.PosePriorBundleAdjustmentOptions()
        # Inlier radius of pycolmap's first similarity alignment to the priors: about 5 sigma, generous
        # because the model's own position errors add to the navigation noise.
        prior_options.alignment_ransac.max_error = 3.0 * np.sqrt(3.0) * camera_position_sigma_m
        prior_options.alignment_ransac.random_seed = int(seed)
        priors = make_pose_priors(reconstruction, prior_positions, prior_covariance(camera_position_sigma_m, tie_point_sigma_px))
        adjuster = pycolmap.create_pose_prior_bundle_adjuster(options, prior_options, config, priors, reconstruction)
    else:
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
        adjuster = pycolmap.create_default_bundle_adjuster(options, config, reconstruction)
    summary = adjuster.solve()
    if not summary.is_solution_usable():
        log.warning("bundle adjustment: no usable solution (%s)", summary.brief_report())
    return summary


# --------------------------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------------------------


@dataclass
class ReconstructionReport:
    """What one reconstruction achieved; :meth:`to_dict` is what the workflow writes as JSON.

    Camera-position quantities are RMS over the registered images of the 3-D
    distance between camera centres (metres). ``cam_pos_rms_m``, the residual
    against the priors, exists only with priors (``None`` otherwise). See
    :func:`pose_report`. The errors against the true cameras are the scoring
    stage's (``evaluation.quality.camera_errors``).
    """

    n_images: int
    n_images_registered: int
    n_points3d: int
    n_observations: int
    mean_track_length: float
    reproj_rms_px: float
    use_priors: bool
    world_frame: str  # "body" (priors on: body frame, metres) or "arbitrary" (a similarity of it)
    camera_position_sigma_m: float | None
    tie_point_sigma_px: float | None
    cam_pos_rms_m: float | None
    cam_pos_rms_expected_m: float | None
    cam_pos_rms_ratio: float | None
    overfit_ratio: float | None
    prior_overfit: bool | None
    intrinsics: str
    focal_px: float
    seconds: float
    stage_seconds: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain types for JSON; NaN (undefined, e.g. an alignment of fewer than 3 cameras) becomes None."""
        return {key: None if isinstance(value, float) and not np.isfinite(value) else value for key, value in asdict(self).items()}


def pose_report(
    body_to_camera: np.ndarray,
    prior_centres: np.ndarray | None,
    camera_position_sigma_m: float | None,
    overfit_ratio: float = DEFAULT_OVERFIT_RATIO,
) -> dict:
    """The prior entries of :class:`ReconstructionReport` for (n, 4, 4) poses and their (n, 3) priors, both in the body frame.

    All ``None`` without priors (``prior_centres`` None): the model then lives
    in a similarity frame of its own, and nothing here knows which.
    """
    entries = dict.fromkeys(("cam_pos_rms_m", "cam_pos_rms_expected_m", "cam_pos_rms_ratio", "overfit_ratio", "prior_overfit"))
    if prior_centres is None:
        return entries
    centres = camera_centres_body(np.asarray(body_to_camera, dtype=float).reshape(-1, 4, 4))
    prior_centres = np.asarray(prior_centres, dtype=float).reshape(-1, 3)
    n = len(centres)
    residual_rms = rms(centres - prior_centres)
    expected = float(camera_position_sigma_m * np.sqrt(max(3.0 - 7.0 / n, 0.0))) if n else float("nan")
    ratio = residual_rms / expected if expected > 0 else float("nan")
    entries.update(
        cam_pos_rms_m=residual_rms, cam_pos_rms_expected_m=expected, cam_pos_rms_ratio=ratio,
        overfit_ratio=float(overfit_ratio), prior_overfit=bool(ratio < overfit_ratio),
    )
    return entries


def model_report(
    model,
    n_images: int,
    prior_positions: np.ndarray | None = None,
    *,
    camera_position_sigma_m: float | None = None,
    tie_point_sigma_px: float | None = None,
    intrinsics_mode: str = "fixed",
    overfit_ratio: float = DEFAULT_OVERFIT_RATIO,
    seconds: float = 0.0,
    stage_seconds: dict | None = None,
    settings: dict | None = None,
) -> ReconstructionReport:
    """The report of a pycolmap model whose images are named ``image_NNN`` (:func:`image_name`).

    ``n_images``: the images of the set; ``prior_positions`` (n_images, 3;
    ``None`` when no priors were used) are indexed by set index.
    """
    use_priors = prior_positions is not None
    registered = sorted((image_index(model.image(image_id).name), image_id) for image_id in model.reg_image_ids())
    registered_indices = np.array([index for index, _ in registered], dtype=int)
    estimated_poses = np.array([pose_matrix(model.image(image_id).cam_from_world()) for _, image_id in registered]).reshape(-1, 4, 4)
    poses = pose_report(
        estimated_poses, np.asarray(prior_positions, dtype=float)[registered_indices] if use_priors else None,
        camera_position_sigma_m, overfit_ratio,
    )
    residuals = reprojection_residuals(model)
    camera = next(iter(model.cameras.values()))
    return ReconstructionReport(
        n_images=int(n_images),
        n_images_registered=int(model.num_reg_images()),
        n_points3d=int(model.num_points3D()),
        n_observations=int(len(residuals)),
        mean_track_length=float(model.compute_mean_track_length()) if model.num_points3D() else 0.0,
        reproj_rms_px=rms(residuals),
        use_priors=use_priors,
        world_frame="body" if use_priors else "arbitrary",
        camera_position_sigma_m=float(camera_position_sigma_m) if use_priors else None,
        tie_point_sigma_px=float(tie_point_sigma_px) if use_priors else None,
        intrinsics=intrinsics_mode,
        focal_px=float(camera.mean_focal_length()),
        seconds=float(seconds),
        stage_seconds=dict(stage_seconds or {}),
        settings=dict(settings or {}),
        **poses,
    )


# --------------------------------------------------------------------------------------------
# The result
# --------------------------------------------------------------------------------------------


def image_name(index: int) -> str:
    """The 8-bit image written for image ``index`` of a set (its index is recoverable from the name)."""
    return f"image_{index:03d}.png"


def image_index(name: str) -> int:
    return int(Path(name).stem.split("_")[-1])


@dataclass
class SparseReconstruction:
    """A sparse model of one set: the pycolmap model, the report and the priors used.

    Images are addressed by their index in the rendered set (``image_NNN``),
    not by COLMAP's image ids. The model's world frame is the body frame
    (metres) when priors were used (``report.world_frame == "body"``), an
    arbitrary similarity frame otherwise.
    """

    model: object  # pycolmap.Reconstruction
    report: ReconstructionReport
    prior_positions: np.ndarray | None = None  # (n_images, 3) navigation priors, body frame, metres

    def _image_ids_by_index(self) -> dict[int, int]:
        return {image_index(self.model.image(image_id).name): image_id for image_id in self.model.reg_image_ids()}

    @property
    def registered_indices(self) -> np.ndarray:
        """Set indices of the registered images, ascending."""
        return np.array(sorted(self._image_ids_by_index()), dtype=int)

    def body_to_camera(self) -> dict[int, np.ndarray]:
        """Estimated 4x4 pose of every registered image: set index -> ``X_cam = R @ X_world + t`` (OpenCV convention).

        The world is the body frame when ``report.world_frame == "body"``.
        """
        return {index: pose_matrix(self.model.image(image_id).cam_from_world()) for index, image_id in sorted(self._image_ids_by_index().items())}

    def camera_centres(self) -> dict[int, np.ndarray]:
        """Estimated camera centre of every registered image (set index -> (3,), world frame)."""
        return {index: np.asarray(self.model.image(image_id).projection_center()) for index, image_id in sorted(self._image_ids_by_index().items())}

    def intrinsics(self) -> Intrinsics:
        """The (single) camera's intrinsics after adjustment (focal length: mean of fx and fy)."""
        camera = next(iter(self.model.cameras.values()))
        return Intrinsics(
            int(camera.width), int(camera.height), float(camera.mean_focal_length()),
            float(camera.principal_point_x), float(camera.principal_point_y),
        )

    def points3d(self) -> tuple[np.ndarray, np.ndarray]:
        """The sparse cloud: ``(point3d_ids (p,), xyz (p, 3))``, world frame, ids ascending."""
        ids = np.array(sorted(self.model.point3D_ids()), dtype=np.int64)
        xyz = np.array([self.model.point3D(int(point_id)).xyz for point_id in ids], dtype=float).reshape(-1, 3)
        return ids, xyz

    def tracks(self) -> dict[str, np.ndarray]:
        """Every observation: ``point`` (row into :meth:`points3d`), ``image`` (set index), ``uv`` (pixels), flat arrays."""
        observations = model_observations(self.model)
        ids, _ = self.points3d()
        index_by_image_id = {image_id: index for index, image_id in self._image_ids_by_index().items()}
        return {
            "point": np.searchsorted(ids, observations.point3d_id),
            "image": np.array([index_by_image_id[int(image_id)] for image_id in observations.image_id], dtype=int),
            "uv": observations.uv,
        }

    def without_images(self, indices, seed: int = 0) -> "SparseReconstruction":
        """A copy of the model with the images of set indices ``indices`` taken out, adjusted again and reported again.

        Each image is deregistered with its observations; a point left in
        fewer than two images goes with them (COLMAP's rule). The rest is
        bundle adjusted as :func:`map_matches` adjusts a mapper's model (with
        the priors it used, if any, and the same ``seed``), and the report
        is made again from it, its settings keeping the mapper's and adding
        ``images_taken_out``. ``ValueError`` for an index that is not
        registered; this model is left as it was.
        """
        import pycolmap

        started = time.perf_counter()
        indices = sorted({int(index) for index in np.asarray(indices, dtype=int).reshape(-1)})
        image_ids = self._image_ids_by_index()
        missing = [index for index in indices if index not in image_ids]
        if missing:
            raise ValueError(f"images {missing} are not registered in the model (registered: {sorted(image_ids)})")
        model = pycolmap.Reconstruction(self.model)
        for index in indices:
            model.deregister_frame(model.image(image_ids[index]).frame_id)
        report = self.report
        sigma_m = report.camera_position_sigma_m if report.camera_position_sigma_m is not None else 1.0
        tie_px = report.tie_point_sigma_px if report.tie_point_sigma_px is not None else 1.0
        _final_bundle_adjustment(model, self.prior_positions, sigma_m, tie_px, report.intrinsics, seed)
        seconds = time.perf_counter() - started
        report = model_report(
            model, report.n_images, self.prior_positions, camera_position_sigma_m=sigma_m, tie_point_sigma_px=tie_px,
            intrinsics_mode=report.intrinsics,
            overfit_ratio=report.overfit_ratio if report.overfit_ratio is not None else DEFAULT_OVERFIT_RATIO,
            seconds=report.seconds + seconds, stage_seconds={**report.stage_seconds, "images_taken_out": seconds},
            settings={**report.settings, "images_taken_out": indices},
        )
        return SparseReconstruction(model, report, self.prior_positions)

    def write(self, out_dir) -> None:
        """Write the model (COLMAP binary, ``model/``), ``report.json`` and ``prior_positions.npy`` to a directory."""
        out_dir = Path(out_dir)
        model_dir = out_dir / "model"
        model_dir.mkdir(parents=True, exist_ok=True)
        self.model.write(model_dir)
        files.write_json(out_dir / "report.json", self.report.to_dict())
        priors_path = out_dir / "prior_positions.npy"
        if self.prior_positions is not None:
            np.save(priors_path, self.prior_positions)
        elif priors_path.exists():
            priors_path.unlink()

    @classmethod
    def read(cls, in_dir) -> "SparseReconstruction":
        """The inverse of :meth:`write`."""
        import pycolmap

        in_dir = Path(in_dir)
        model = pycolmap.Reconstruction()
        model.read(in_dir / "model")
        report = ReconstructionReport(**json.loads((in_dir / "report.json").read_text()))
        priors_path = in_dir / "prior_positions.npy"
        return cls(model, report, np.load(priors_path) if priors_path.exists() else None)


# --------------------------------------------------------------------------------------------
# The pipeline
# --------------------------------------------------------------------------------------------


@dataclass
class FeatureOptions:
    """SIFT and matching settings (COLMAP's defaults unless measured otherwise)."""

    max_num_features: int = 8192
    peak_threshold: float = 0.02 / 3  # COLMAP's default
    upright: bool = False
    domain_size_pooling: bool = False
    guided_matching: bool = False
    max_ratio: float = 0.8
    # Which pairs are matched: None, every pair; a number, only the pairs whose rotation phases (from the
    # image times) differ by at most this many degrees (:func:`rotation_pairs`).
    max_turn_deg: float | None = None
    # The mapper's image registration (COLMAP: abs_pose_min_num_inliers 30, abs_pose_min_inlier_ratio
    # 0.25). With ~400 features per image on the k = 0.7 sets, 30 inliers split the mapper into
    # 3 models of 16, 15 and 11 images; 15 and 0.1 register all 36 with unchanged reprojection
    # RMS and camera accuracy (0.41-0.44 px, 1.65 m with priors), and change nothing on sets
    # that registered already (light10_albedo0.5_k1: the same 1888 points and cameras).
    min_pose_inliers: int = 15
    min_pose_inlier_ratio: float = 0.1


#: Threads of the incremental mapper and of the bundle adjustments. One, for the same model on every
#: run: Ceres sums the cost and gradient of a multi-threaded evaluation in the order its threads finish
#: (COLMAP turns threading on above 50000 residuals; these sets have about 12000, so one thread costs
#: nothing here). Extraction (per image) is the same at any thread count, once the image ids are fixed
#: (``reconstruct_images``); matching is not (``MATCHING_THREADS``).
MAPPING_THREADS = 1

#: Threads of the feature matching, whatever ``num_threads`` asks. One, for the same matches on every
#: run: on two, COLMAP's CPU matcher builds the descriptor indexes it shares between its threads at the
#: same time, and 1 run in 60 of the 18-image test set (tests/test_reconstruct.py) gave the first
#: image's first two pairs 55 and 16 matches instead of 124 and 39. The exact matcher
#: (``cpu_brute_force_matcher``) has no shared index but took 28 s instead of 2 s on a 36-image set;
#: one thread of the index matcher is what the workflow ran already (rule match_features).
MATCHING_THREADS = 1


def _pycolmap_options(features: FeatureOptions, use_priors: bool, num_threads: int, seed: int) -> dict:
    import pycolmap

    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    extraction.use_gpu = False
    extraction.sift.max_num_features = features.max_num_features
    extraction.sift.peak_threshold = features.peak_threshold
    extraction.sift.upright = features.upright
    extraction.sift.domain_size_pooling = features.domain_size_pooling

    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = MATCHING_THREADS
    matching.use_gpu = False
    matching.guided_matching = features.guided_matching
    matching.sift.max_ratio = features.max_ratio

    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed

    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = MAPPING_THREADS
    mapping.random_seed = seed
    mapping.extract_colors = False
    # The mapper always holds the intrinsics; "refine" frees the focal lengths in the final
    # adjustment only. Refining them during incremental mapping is ill-conditioned for this
    # narrow field of view (focal length and distance trade off): on light10_albedo0.7_k0.8 it
    # registered 19 of 36 images with f = 2041 px (true 3561 px) with priors, 2 of 36 with
    # f = 3.1e5 px without.
    mapping.ba_refine_focal_length = False
    mapping.ba_refine_principal_point = False
    mapping.ba_refine_extra_params = False
    mapping.use_prior_position = use_priors
    mapping.mapper.abs_pose_min_num_inliers = features.min_pose_inliers
    mapping.mapper.abs_pose_min_inlier_ratio = features.min_pose_inlier_ratio
    return {"extraction": extraction, "matching": matching, "verification": verification, "mapping": mapping}


#: The SIFT and matching fields of :class:`FeatureOptions` (the others are the mapper's): what a matched set records.
MATCHING_FIELDS = ("max_num_features", "peak_threshold", "upright", "domain_size_pooling", "guided_matching", "max_ratio", "max_turn_deg")

#: A matched set's summary (:func:`match_images`), beside its ``images/`` and ``database.db``.
MATCHES_FILE = "matches.json"

#: The seed of the two-view verification's RANSAC in a matched set shared by several mapper runs (``experiments.table2``).
MATCHING_SEED = 0


def _extract_features(image_dir: Path, database_path: Path, names: list[str], intrinsics: Intrinsics, extraction_options) -> None:
    """A new database of the images (one pinhole camera, the known intrinsics), and their SIFT features."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    reader.camera_params = f"{intrinsics.focal_px!r},{intrinsics.focal_px!r},{intrinsics.cx!r},{intrinsics.cy!r}"
    # The images enter the database one by one in set order first: the extractor numbers images in the
    # order its threads finish them, and the mapper's choices (initial pair, next image) follow the ids.
    with pycolmap.Database.open(database_path):  # a new, empty database
        pass
    pycolmap.import_images(database_path, image_dir, camera_mode=pycolmap.CameraMode.SINGLE, image_names=names, options=reader)
    pycolmap.extract_features(
        database_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader, extraction_options=extraction_options, device=pycolmap.Device.cpu,
    )


def _keypoint_counts(database_path) -> dict[str, int]:
    """The number of keypoints of each image (by name)."""
    import pycolmap

    with pycolmap.Database.open(database_path) as database:
        n_keypoints = {image.name: database.num_keypoints_for_image(image.image_id) for image in database.read_all_images()}
    log.info("SIFT: %d to %d keypoints per image (median %d)", min(n_keypoints.values()), max(n_keypoints.values()), int(np.median(list(n_keypoints.values()))))
    return n_keypoints


def _write_pose_priors(database_path, prior_centres: np.ndarray, camera_position_sigma_m: float, tie_point_sigma_px: float) -> None:
    """The navigation priors ``prior_centres`` (one row per image, set order) written to the database as pose priors."""
    import pycolmap

    covariance = prior_covariance(camera_position_sigma_m, tie_point_sigma_px)
    with pycolmap.Database.open(database_path) as database:
        for image in database.read_all_images():
            database.write_pose_prior(
                pycolmap.PosePrior(
                    corr_data_id=image.data_id, position=prior_centres[image_index(image.name)],
                    position_covariance=covariance, coordinate_system=pycolmap.PosePriorCoordinateSystem.CARTESIAN,
                )
            )


def _verified_pairs(database_path) -> int:
    """The number of image pairs whose two-view geometry the verification accepted (with inlier matches).

    Not ``Database.num_verified_image_pairs``: that counts every pair the
    verification looked at, accepted or not (all 435 pairs of a 30-image set
    whose images have no feature in common).
    """
    import pycolmap

    with pycolmap.Database.open(database_path) as database:
        pair_ids, _ = database.read_two_view_geometry_num_inliers()
        n_checked = database.num_verified_image_pairs()
    log.info("%d image pairs verified with inlier matches, of %d checked", len(pair_ids), n_checked)
    return len(pair_ids)


def _largest_model(models: dict, n_images: int, n_verified_pairs: int):
    """The mapper's model with the most registered images; :class:`DataFailure` if it has fewer than ``MIN_REGISTERED_IMAGES``."""
    sizes = {key: model.num_reg_images() for key, model in models.items()}
    if max(sizes.values(), default=0) < MIN_REGISTERED_IMAGES:
        from asteroid_photometry.core.failures import DataFailure

        raise DataFailure(
            f"pycolmap registered {max(sizes.values(), default=0)} of {n_images} images in its largest model "
            f"(at least {MIN_REGISTERED_IMAGES} needed; {n_verified_pairs} verified image pairs; where few pairs verify, as at "
            f"20 images per turn, reconstruction.guided_matching: true with match_max_ratio: 0.9 finds more matches, and "
            f"reconstruction.match_max_turn_deg keeps them to images that share surface)"
        )
    model = models[max(sizes, key=sizes.get)]
    log.info("mapper: %d model(s) with %s registered images; keeping the largest", len(models), sorted(sizes.values(), reverse=True))
    return model


def _final_bundle_adjustment(model, prior_centres, camera_position_sigma_m: float, tie_point_sigma_px: float, intrinsics_mode: str, seed: int) -> None:
    """``bundle_adjust`` of the model, with the navigation priors ``prior_centres`` of its registered images (None: none)."""
    index_by_image_id = {image_id: image_index(model.image(image_id).name) for image_id in model.reg_image_ids()}
    priors_by_image_id = {image_id: prior_centres[index] for image_id, index in index_by_image_id.items()} if prior_centres is not None else None
    bundle_adjust(
        model, priors_by_image_id, camera_position_sigma_m=camera_position_sigma_m, tie_point_sigma_px=tie_point_sigma_px,
        refine_intrinsics=intrinsics_mode == "refine", num_threads=MAPPING_THREADS, seed=seed,
    )


def _warn_if_far_from_priors(report: ReconstructionReport) -> None:
    if report.cam_pos_rms_m is not None and report.cam_pos_rms_m > 10.0 * report.cam_pos_rms_expected_m:
        log.warning(
            "the cameras are %.3g m RMS from their priors, more than 10 times the %.3g m expected: "
            "pycolmap's alignment to the priors may have failed and the model may not be in the body frame",
            report.cam_pos_rms_m, report.cam_pos_rms_expected_m,
        )


#: How far a camera may sit, round the ring the cameras make, from where its image's time puts it: a fraction of the
#: turn between consecutive images, the bound excluded. A camera that far has reached its neighbour's place. The check's
#: other half is the image order itself (:func:`ring_order`): every camera between its two neighbours. Both are set by what
#: the check means, not fitted to any set. Measured (docs/table2.md, section 1): sound models put every camera within 0.16
#: of a turn between images of its place (the paper's sets, all four imaging conditions, two runs; 45 models of
#: tuning_mid's and the map sets), but for three models of the tuning grid (k 0.55, without priors, at 30 and 20 images
#: a turn) with two neighbours 0.35 to 0.74 from their places, in order, where a weakly tied part of the ring left them
#: (their errors against the true cameras the same); the mapper closed a ring wrongly twice: 18 turns between images
#: (171 degrees) on a paper set, one image placed on another's (1.9, out of order) on the grid.
RING_ORDER_TOLERANCE_STEPS = 1.0


def ring_step_deg(phase_deg) -> float:
    """The median turn (degrees) between consecutive images of a ring, from their rotation phases (modulo 360)."""
    phase = np.sort(np.unique(np.round(np.asarray(phase_deg, dtype=float) % 360.0, 9)))
    if phase.size < 2:
        raise ValueError(f"a ring needs at least two distinct rotation phases, got {phase.size}")
    return float(np.median(np.diff(np.append(phase, phase[0] + 360.0))))


def ring_order_residuals_deg(centres, phase_deg) -> np.ndarray:
    """How far each camera sits round the ring of the cameras from where its rotation phase puts it (degrees, positive
    ahead of its place in the direction the cameras go).

    ``centres`` (n, 3): camera centres in any frame (a similarity of the body
    frame: a model without priors); ``phase_deg`` (n,): each image's rotation
    phase from its time. The body turns under a camera fixed in space, so in
    the body frame the cameras of a sequence go round one circle, each at its
    phase. The circle is fitted (the plane of the centres, then the circle in
    it by least squares), each centre's angle round it taken, and the phases
    matched to the angles up to a common offset and the direction of travel:
    the residuals are what is left. A model the mapper closed wrongly puts
    whole runs of cameras tens of degrees or more from their place.
    """
    centres = np.asarray(centres, dtype=float).reshape(-1, 3)
    phase = np.asarray(phase_deg, dtype=float).reshape(-1)
    if len(centres) < 3 or len(phase) != len(centres):
        raise ValueError(f"the ring check needs at least 3 cameras with one phase each, got {len(centres)} centres and {len(phase)} phases")
    offsets = centres - centres.mean(axis=0)
    basis = np.linalg.svd(offsets, full_matrices=False)[2][:2]
    xy = offsets @ basis.T
    design = np.column_stack([2.0 * xy, np.ones(len(xy))])
    (cx, cy, _), *_ = np.linalg.lstsq(design, np.sum(xy**2, axis=1), rcond=None)
    angle = np.degrees(np.arctan2(xy[:, 1] - cy, xy[:, 0] - cx))
    best = None
    for direction in (1.0, -1.0):
        difference = np.radians(angle - direction * phase)
        offset = np.degrees(np.angle(np.exp(1j * difference).mean()))
        residual = (np.degrees(difference) - offset + 180.0) % 360.0 - 180.0
        if best is None or np.sum(residual**2) < np.sum(best**2):
            best = direction * residual  # positive: ahead of its place, the way the cameras go
    return best


@dataclass(frozen=True)
class RingOrder:
    """How a model's cameras go round their ring against their images' rotation phases (:func:`ring_order`)."""

    error_steps: float  # the largest distance of a camera from its place, in turns between consecutive images
    order_kept: bool  # every camera between its two neighbours in the image order

    @property
    def sound(self) -> bool:
        """Whether the cameras keep the image order, none as far as a neighbour's place (``RING_ORDER_TOLERANCE_STEPS``)."""
        return self.order_kept and self.error_steps < RING_ORDER_TOLERANCE_STEPS


def ring_order(centres, phase_deg) -> RingOrder:
    """The ring check of a model's camera centres (any similarity frame) against their images' rotation phases.

    The largest of :func:`ring_order_residuals_deg` in turns between consecutive images (:func:`ring_step_deg`), and
    whether the cameras keep the image order: going from image to image in the order of their phases (round the ring
    and back to the first), each camera must advance round the circle the way the others go. A folded run or two cameras in each other's place go back; a camera
    a weak part of the model leaves half a turn between images out of place does not.
    """
    phase = np.asarray(phase_deg, dtype=float).reshape(-1)
    residual = ring_order_residuals_deg(centres, phase)
    step = ring_step_deg(phase)
    order = np.argsort(phase % 360.0, kind="stable")
    turn = np.diff(np.append(phase[order] % 360.0, phase[order[0]] % 360.0 + 360.0))
    # The residuals are measured the way the cameras go, so a step's advance round the circle is its turn plus the change
    # of residual; where two images share a phase there is no order to keep.
    advance = turn + np.diff(np.append(residual[order], residual[order[0]]))
    kept = bool(np.all(advance[turn > 1e-6 * step] > 0.0))
    return RingOrder(float(np.max(np.abs(residual)) / step), kept)


#: The largest share of a model's registered cameras that may be taken out of it to leave the rest a sound ring
#: (:func:`ring_outliers`): one in ten. A model most of whose ring is sound, with a camera or two the mapper placed wrongly
#: (at the open end of an arc, where the last images register on few points), is kept without them rather than lost;
#: one that needs more taken out is not one ring with a few stray cameras. Set by what it means, not fitted: the case
#: that asked for it (tuning_mid, light 0, albedo 0.6, k 0.75 without priors: the last two of 24 registered cameras
#: 0.6 and 1.6 turns between images back, out of order, on every mapper seed) needs two.
MAX_RING_OUTLIER_SHARE = 0.1


def ring_outliers(centres, phase_deg, max_removed: int) -> np.ndarray | None:
    """The cameras (rows of ``centres``) to take out of a model so that the rest make a sound ring (:func:`ring_order`).

    Taken one at a time, the camera farthest from its place first, the
    circle fitted again to those left each time. Empty for a sound ring;
    ``None`` where more than ``max_removed`` would have to go, or fewer than
    three cameras would be left. Rows ascending.
    """
    centres = np.asarray(centres, dtype=float).reshape(-1, 3)
    phase = np.asarray(phase_deg, dtype=float).reshape(-1)
    kept = np.arange(len(centres))
    while len(kept) >= 3:
        if ring_order(centres[kept], phase[kept]).sound:
            return np.setdiff1d(np.arange(len(centres)), kept)
        if len(centres) - len(kept) >= max_removed:
            return None
        kept = np.delete(kept, np.argmax(np.abs(ring_order_residuals_deg(centres[kept], phase[kept]))))
    return None


def rotation_pairs(phase_deg, max_turn_deg: float) -> list[tuple[int, int]]:
    """The image pairs ``(i, j)``, ``i < j``, whose rotation phases ``phase_deg`` differ by at most ``max_turn_deg`` (modulo 360).

    The body turns between two images by the difference of their phases, so
    these are the pairs that can share surface. Matching only them keeps the
    two-view verification from accepting false matches between images that
    share none (``FeatureOptions.max_turn_deg``). Each image needs at least
    one partner: a ``ValueError`` names the first that has none.
    """
    phase = np.asarray(phase_deg, dtype=float)
    difference = np.abs(phase[:, None] - phase[None, :]) % 360.0
    close = np.minimum(difference, 360.0 - difference) <= max_turn_deg + 1e-9
    np.fill_diagonal(close, False)
    alone = np.flatnonzero(~close.any(axis=1))
    if alone.size:
        raise ValueError(
            f"image {int(alone[0])} has no other image within {max_turn_deg:g} deg of rotation "
            f"(reconstruction.match_max_turn_deg); raise it above the turn between consecutive images"
        )
    first, second = np.nonzero(np.triu(close, k=1))
    return list(zip(first.tolist(), second.tolist()))


def _match(database_path: Path, names: list[str], pairs, options: dict) -> None:
    """COLMAP's matching and two-view verification: every pair (``pairs`` None), or those of ``pairs`` (index pairs), listed in ``pairs.txt`` beside the database."""
    import pycolmap

    if pairs is None:
        pycolmap.match_exhaustive(database_path, matching_options=options["matching"], verification_options=options["verification"], device=pycolmap.Device.cpu)
        return
    pair_list = database_path.parent / PAIRS_FILE
    pair_list.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    pairing = pycolmap.ImportedPairingOptions()
    pairing.match_list_path = str(pair_list)
    pycolmap.match_image_pairs(
        database_path, matching_options=options["matching"], pairing_options=pairing, verification_options=options["verification"], device=pycolmap.Device.cpu,
    )


#: The pairs a matched set matched, when not every pair (:func:`rotation_pairs`), one line per pair of image names.
PAIRS_FILE = "pairs.txt"


def match_images(
    images,
    intrinsics: Intrinsics,
    out_dir,
    *,
    tone_curve: str = DEFAULT_TONE_CURVE,
    features: FeatureOptions | None = None,
    phase_deg=None,
    num_threads: int = 1,
    seed: int = MATCHING_SEED,
) -> dict:
    """Steps 1 and 2 of a reconstruction (module docstring): the 8-bit images, their SIFT features and verified matches.

    ``images``: linear float images (list of (H, W) arrays, set order).
    ``out_dir`` receives the 8-bit images (``images/``), the COLMAP database
    with one shared pinhole camera of the known ``intrinsics``, the
    keypoints, the matches and the verified two-view geometries
    (``database.db``), and a summary (``MATCHES_FILE``, returned too: the
    images, tone curve and reference brightness, the SIFT and matching
    settings, keypoints per image, verified pairs, the seconds of each
    step), each replaced if present. No navigation prior enters here: the
    same matched set serves a reconstruction with priors and one without
    (:func:`map_matches`). ``phase_deg``: each image's rotation phase
    (degrees), needed when ``features.max_turn_deg`` limits the pairs
    (:func:`rotation_pairs`). ``num_threads`` as :func:`reconstruct_images`;
    ``seed`` seeds the two-view verification's RANSAC.
    """
    import pycolmap

    features = FeatureOptions() if features is None else features
    pairs = None
    if features.max_turn_deg is not None:
        if phase_deg is None or len(phase_deg) != len(images):
            raise ValueError(f"max_turn_deg {features.max_turn_deg:g} needs the rotation phase of each of the {len(images)} images")
        pairs = rotation_pairs(phase_deg, features.max_turn_deg)
    out_dir = Path(out_dir)
    image_dir, database_path = out_dir / "images", out_dir / "database.db"
    shutil.rmtree(image_dir, ignore_errors=True)  # only what this function writes: a rerun starts clean
    database_path.unlink(missing_ok=True)
    (out_dir / PAIRS_FILE).unlink(missing_ok=True)
    pycolmap.set_random_seed(seed)
    names = [image_name(i) for i in range(len(images))]
    reference = write_images(images, names, image_dir, tone_curve)
    options = _pycolmap_options(features, False, num_threads, seed)
    stage_seconds = {}

    tick = time.perf_counter()
    _extract_features(image_dir, database_path, names, intrinsics, options["extraction"])
    stage_seconds["features"] = time.perf_counter() - tick
    n_keypoints = _keypoint_counts(database_path)

    tick = time.perf_counter()
    _match(database_path, names, pairs, options)
    stage_seconds["matching"] = time.perf_counter() - tick

    summary = {
        "n_images": len(images), "tone_curve": tone_curve, "reference_brightness": reference, "seed": int(seed),
        "features": {key: getattr(features, key) for key in MATCHING_FIELDS},
        "n_keypoints": n_keypoints, "median_keypoints": int(np.median(list(n_keypoints.values()))),
        "n_pairs_matched": len(images) * (len(images) - 1) // 2 if pairs is None else len(pairs),
        "n_verified_pairs": int(_verified_pairs(database_path)), "stage_seconds": stage_seconds,
    }
    files.write_json(out_dir / MATCHES_FILE, summary)
    return summary


def read_matches(matches_dir) -> dict:
    """The summary :func:`match_images` wrote to ``matches_dir``, its images and database checked present."""
    matches_dir = Path(matches_dir)
    for path in (matches_dir / MATCHES_FILE, matches_dir / "database.db", matches_dir / "images"):
        if not path.exists():
            raise FileNotFoundError(f"{path} is missing: {matches_dir} is not a complete matched set (match_images)")
    return json.loads((matches_dir / MATCHES_FILE).read_text())


def map_matches(
    matches_dir,
    work_dir,
    *,
    prior_positions: np.ndarray | None = None,
    intrinsics_mode: str = "fixed",
    camera_position_sigma_m: float = 1.0,
    tie_point_sigma_px: float = 1.0,
    features: FeatureOptions | None = None,
    overfit_ratio: float = DEFAULT_OVERFIT_RATIO,
    seed: int = 0,
) -> SparseReconstruction:
    """Steps 3 to 5 of a reconstruction (module docstring) from a matched set (:func:`match_images`, in ``matches_dir``).

    ``matches_dir`` is only read. Its database is copied to ``work_dir``,
    the pose priors are written into the copy where given, the mapper
    writes its models to ``work_dir/mapper`` (replaced if present), and the
    copy is removed when the model is done. ``prior_positions`` (n, 3),
    ``intrinsics_mode``, the accuracies and ``overfit_ratio`` as
    :func:`reconstruct_images`. ``features`` gives the mapper's
    registration thresholds; its SIFT and matching fields must be those the
    set was matched with (``ValueError`` if not). ``seed`` seeds the
    mapper's and the final adjustment's RANSACs and sampling, not the
    matches: those are the matched set's. The report's ``stage_seconds``
    take ``features`` and ``matching`` from the matched set, and its
    ``seconds`` count them too.
    """
    import pycolmap

    if intrinsics_mode not in ("fixed", "refine"):
        raise ValueError(f"intrinsics must be 'fixed' or 'refine', got {intrinsics_mode!r}")
    matches_dir, work_dir = Path(matches_dir), Path(work_dir)
    matched = read_matches(matches_dir)
    n_images = matched["n_images"]
    use_priors = prior_positions is not None
    if use_priors:
        prior_positions = np.asarray(prior_positions, dtype=float)
        if prior_positions.shape != (n_images, 3):
            raise ValueError(f"{n_images} images but prior positions of shape {prior_positions.shape}; expected ({n_images}, 3)")
    features = FeatureOptions() if features is None else features
    differing = {key: (getattr(features, key), matched["features"][key]) for key in MATCHING_FIELDS if getattr(features, key) != matched["features"][key]}
    if differing:
        raise ValueError(f"{matches_dir} was matched with other settings (asked, matched): {differing}")
    started = time.perf_counter()
    stage_seconds = {key: matched["stage_seconds"][key] for key in ("features", "matching")}
    pycolmap.set_random_seed(seed)

    database_path, mapper_dir = work_dir / "database.db", work_dir / "mapper"
    shutil.rmtree(mapper_dir, ignore_errors=True)  # only what this function writes: a rerun starts clean
    mapper_dir.mkdir(parents=True)
    shutil.copyfile(matches_dir / "database.db", database_path)  # the matched set's own stays as it is
    if use_priors:
        _write_pose_priors(database_path, prior_positions, camera_position_sigma_m, tie_point_sigma_px)
    options = _pycolmap_options(features, use_priors, 1, seed)

    tick = time.perf_counter()
    models = pycolmap.incremental_mapping(database_path, matches_dir / "images", mapper_dir, options["mapping"])
    stage_seconds["mapping"] = time.perf_counter() - tick
    database_path.unlink()  # the matched set's database and the priors: nothing the model needs
    model = _largest_model(models, n_images, matched["n_verified_pairs"])

    tick = time.perf_counter()
    _final_bundle_adjustment(model, prior_positions, camera_position_sigma_m, tie_point_sigma_px, intrinsics_mode, seed)
    stage_seconds["final_bundle_adjustment"] = time.perf_counter() - tick

    report = model_report(
        model, n_images, prior_positions, camera_position_sigma_m=camera_position_sigma_m,
        tie_point_sigma_px=tie_point_sigma_px, intrinsics_mode=intrinsics_mode, overfit_ratio=overfit_ratio,
        seconds=time.perf_counter() - started + stage_seconds["features"] + stage_seconds["matching"], stage_seconds=stage_seconds,
        settings={
            "tone_curve": matched["tone_curve"], "reference_brightness": matched["reference_brightness"], "seed": int(seed),
            "features": asdict(features), "n_models": len(models), "n_verified_pairs": int(matched["n_verified_pairs"]),
            "median_keypoints": int(matched["median_keypoints"]),
        },
    )
    if use_priors:
        _warn_if_far_from_priors(report)
    log.info("reconstruction: %s", json.dumps(report.to_dict()))
    return SparseReconstruction(model, report, prior_positions)


def reconstruct_images(
    images,
    intrinsics: Intrinsics,
    work_dir,
    *,
    prior_positions: np.ndarray | None = None,
    intrinsics_mode: str = "fixed",
    camera_position_sigma_m: float = 1.0,
    tie_point_sigma_px: float = 1.0,
    tone_curve: str = DEFAULT_TONE_CURVE,
    features: FeatureOptions | None = None,
    overfit_ratio: float = DEFAULT_OVERFIT_RATIO,
    num_threads: int = 1,
    seed: int = 0,
) -> SparseReconstruction:
    """Sparse reconstruction of one set of linear float images (list of (H, W) arrays, set order): :func:`match_images`, then :func:`map_matches`.

    ``work_dir`` receives the matched set (``features/``: the 8-bit images,
    the COLMAP database, its summary) and the mapper's models (``mapper/``),
    each replaced if present. ``prior_positions`` (n, 3), the navigation
    solution's camera centres in the body frame (metres), accurate to
    ``camera_position_sigma_m`` per axis, are the pose priors; ``None``
    reconstructs without priors. ``intrinsics_mode`` is ``"fixed"`` (the
    known intrinsics, never refined) or ``"refine"`` (focal lengths refined
    in the final bundle adjustment). ``num_threads`` is for feature
    extraction (-1: all cores, COLMAP's convention); matching runs on
    ``MATCHING_THREADS``, mapping and bundle adjustment on
    ``MAPPING_THREADS``. ``seed`` seeds pycolmap's RANSACs (the two-view
    verification's among them) and mapper: the same images, settings and
    seed give the same model, bit for bit, at any ``num_threads``. (Matching
    on more threads made thread timing reach the matches: a loaded machine
    gave a model of 1515 points instead of 1539 from the same images.)
    """
    if prior_positions is not None and np.shape(prior_positions) != (len(images), 3):  # before any work
        raise ValueError(f"{len(images)} images but prior positions of shape {np.shape(prior_positions)}; expected ({len(images)}, 3)")
    matches_dir = Path(work_dir) / "features"
    match_images(images, intrinsics, matches_dir, tone_curve=tone_curve, features=features, num_threads=num_threads, seed=seed)
    return map_matches(
        matches_dir, work_dir, prior_positions=prior_positions, intrinsics_mode=intrinsics_mode, camera_position_sigma_m=camera_position_sigma_m,
        tie_point_sigma_px=tie_point_sigma_px, features=features, overfit_ratio=overfit_ratio, seed=seed,
    )
