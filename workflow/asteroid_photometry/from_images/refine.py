"""Photometric refinement of a reconstructed cloud (Iwano's Eq. 7; the paper's future work): positions and normals.

A multi-view-stereo normal is a local plane fit through noisy points, a
dozen degrees off on Itokawa, and a SIFT point sits where the image changes:
on a facet's edge or corner, so its samples mix neighbouring facets in every
image. Both spoil the estimator (the ``geometry_sensitivity`` study measures
by how much). The refinement therefore moves the samples as well as the
normals (:func:`refine_by_pure_samples`):

1. candidate points are drawn uniformly on a surface through the cloud
   (its Poisson surface), with that surface's normals;
2. each candidate is slid along its normal over a few pixels' worth of
   offsets, and at every offset sampled only where the image itself shows
   the sample pure (``cloud.sample_pure``: the four pixels of a bilinear
   sample agree), in every image that sees it;
3. with at least ``min_observations`` pure samples, the candidate's normal,
   albedo and k are fitted to them with the light fixed at the estimator's
   value (a Levenberg-Marquardt step per point, vectorised over all points:
   4x4 normal equations per point, solved in one batched call, with the
   surface's normal as a Gaussian prior); the offset whose samples one
   facet explains best (smallest relative RMS residual) is kept, and a
   candidate is accepted when that residual is small: samples from two
   facets do not fit one normal;
4. the light is fitted again to the accepted points' pure samples, with
   their normals held and one Minnaert k for the whole body
   (``estimate.fit_pooled_k``); with the normals free to tilt (below), one
   albedo for the whole body too (:func:`one_albedo`);
5. the estimator runs again on the accepted points, with their fitted
   normals and pure samples; the paper's estimator fits each point's
   albedo and k under step 4's light.

The normal only turns about the body's spin axis (the normal of the plane
of the camera centres, ``spin_axis``): seen from a ring of views with the
Sun in its plane, a point's brightness fixes its normal's longitude, while
a latitude error only scales the brightness by ``cos(lat)^(2k - 1)``, which
the point's albedo absorbs. Left free, the latitude wanders with whatever
the light's elevation is (flattened on one run, -0.008 in the mean albedo);
held at the surface's, it costs only albedo scatter. That holds only in the
plane: with the views or the Sun out of the ring's plane (by more than
``IN_PLANE_LIMIT_DEG``, measured by :func:`turn_axis` from the cameras and
the starting light), a latitude error changes the brightness differently in
each view, the data constrain it, and the normals tilt about both axes.

Two parts of the light behave differently. Its azimuth (about the spin
axis) the refinement keeps from where it started: a common turn of the
normals and the light about that axis changes only the weak
``cos_o^(k - 1)`` factor, so the fitted longitudes follow the starting
light (a second refinement pass under step 4's light moved its azimuth by
0.01 deg or less on three sets). Its elevation, out of the plane of the
views and the Sun, is what a free k per point cannot hold
(``estimate.fit_pooled_k`` says why): on the 16 sets with priors the
paper's joint fit on the pure samples leaves the light 0.17 to 1.86 deg
off, and step 4, with one k, 0.07 to 0.40 deg.

With the normals free to tilt, an albedo per point is not enough either:
normals fitted under a light a few degrees off, each with its own albedo,
explain the samples about as well as the true light does, so step 4 keeps
the light it started from (the `oblique` condition: 5.8 to 6.9 deg off; an
albedo per region of the body, 40 regions, 8 to 10). Step 4 then fits one
albedo for the whole body (:func:`one_albedo`): the light is what makes
points of different normals differ in brightness, and an albedo that varies
over the body, unrelated to the normals' direction, is scatter to that
comparison. On `oblique` it brings the light to 0.3 to 1.5 deg; the
per-point albedo and k are then fitted under it as before. What one albedo
pins is the elevation; where the albedo varies over the body it also moves
the azimuth, which the start held (on config/conditions_geometry.yaml's
`oblique` rows from 0.2 to 0.7 deg off to 1.7 to 1.9), so the light step's
light keeps the start's azimuth about the spin axis and takes its elevation
from one albedo (:func:`keep_azimuth`). And each pass's normals follow the
light they were fitted under, so the step takes only part of its elevation
error off: the refinement runs again from the step's light until it settles
(:func:`refine_until_settled`). In the ring's plane the normals turn about
the spin axis only and step 4 keeps an albedo per point: there one albedo
for the body puts the light 0.5 to 7.9 deg off on the `amica` sets, where
per-point albedo gives 0.25 to 3.1.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.special import chdtri

from asteroid_photometry.core import files
from asteroid_photometry.estimation import angle_between_deg, fit_pooled_k, Observations
from asteroid_photometry.estimation.hierarchical import fit_light_k_prior
from asteroid_photometry.from_images import cloud as cloud_lib
from asteroid_photometry.reflectance.laws import minnaert_brightness
from asteroid_photometry.world.cameras import camera_centres_body, Intrinsics

log = logging.getLogger(__name__)

COS_FLOOR = 1e-6


def _tangent_basis(normals):
    helper = np.where(np.abs(normals[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(normals, e1)


def _turn(normals, axis, angle):
    """``normals`` turned about ``axis`` (unit) by ``angle`` (rad, one per row): Rodrigues' formula."""
    cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
    along = (normals @ axis)[:, None] * axis
    return normals * cos + np.cross(axis, normals) * sin + along * (1.0 - cos)


def spin_axis(camera_centres) -> np.ndarray:
    """The axis the body turns about, from the cameras alone: the normal of the best plane through their centres (unit, sign arbitrary)."""
    centres = np.asarray(camera_centres, dtype=float)
    _, _, vt = np.linalg.svd(centres - centres.mean(axis=0))
    return vt[2]


def ring_axis_cam(body_to_camera: dict) -> np.ndarray:
    """The spin axis (:func:`spin_axis`) in the cameras' frame: the mean over the images (one direction for a ring of views)."""
    poses = np.array(list(body_to_camera.values()))
    axis = spin_axis(camera_centres_body(poses))
    in_cameras = poses[:, :3, :3] @ axis
    mean = in_cameras.mean(axis=0)
    return mean / np.linalg.norm(mean)


def keep_azimuth(light_dir_cam, azimuth_from, axis_cam) -> np.ndarray:
    """``light_dir_cam``'s elevation out of the plane normal to ``axis_cam``, turned to ``azimuth_from``'s azimuth in that plane (unit)."""
    axis = np.asarray(axis_cam, dtype=float) / np.linalg.norm(axis_cam)
    light = np.asarray(light_dir_cam, dtype=float) / np.linalg.norm(light_dir_cam)
    elevation = np.arcsin(np.clip(light @ axis, -1.0, 1.0))
    source = np.asarray(azimuth_from, dtype=float)
    in_plane = source - (source @ axis) * axis
    return np.cos(elevation) * in_plane / np.linalg.norm(in_plane) + np.sin(elevation) * axis


#: Above this angle (deg) of the views or of the light out of the plane of the camera ring, a normal's latitude
#: changes its brightness differently in each view (no longer a scale its albedo absorbs): the refinement then
#: tilts the normals about both axes (:func:`turn_axis`). In-plane sets sit near 0 (their cloud estimates' light
#: is at most 4 deg out of the plane, on the paper's sets and the tuning grid); the `oblique` condition at 20.
IN_PLANE_LIMIT_DEG = 10.0


def turn_axis(body_to_camera: dict, centre, light_dir_cam, limit_deg: float = IN_PLANE_LIMIT_DEG):
    """The axis the refinement turns normals about, and how far the views and the light leave the camera ring's plane.

    Returns ``(axis, view_deg, light_deg)``: the angles are medians over the
    images of the angle between the ring's plane (normal :func:`spin_axis`)
    and the view from each camera to ``centre``, and the light
    (``light_dir_cam`` in each camera's frame) taken to the reconstruction
    frame. ``axis`` is the spin axis when both are within ``limit_deg``, else
    None (normals tilt freely).
    """
    poses = np.array(list(body_to_camera.values()))
    centres = camera_centres_body(poses)
    axis = spin_axis(centres)
    views = np.asarray(centre, dtype=float) - centres
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    light = np.einsum("nji,j->ni", poses[:, :3, :3], np.asarray(light_dir_cam, dtype=float) / np.linalg.norm(light_dir_cam))
    view_deg, light_deg = (float(np.degrees(np.median(np.arcsin(np.clip(np.abs(v @ axis), 0.0, 1.0))))) for v in (views, light))
    return (axis if max(view_deg, light_deg) <= limit_deg else None), view_deg, light_deg


def _model(normals_obs, light_b, view_b, albedo_obs, k_obs):
    """The Minnaert brightness of each observation (cosines floored at ``COS_FLOOR``, so every row is lit), and the cosines."""
    cos_i = np.maximum(np.einsum("ij,ij->i", normals_obs, light_b), COS_FLOOR)
    cos_o = np.maximum(np.einsum("ij,ij->i", normals_obs, view_b), COS_FLOOR)
    return minnaert_brightness(albedo_obs, k_obs, cos_i, cos_o), cos_i, cos_o


#: A point of :func:`refine_points` is converged, and no longer iterated, when its LM damping has grown past
#: FROZEN_DAMPING (steps of about 1e-3 of a Gauss-Newton step, after some ten failed ones) or its last step
#: lowered its cost by less than CONVERGED_DECREASE of it.
FROZEN_DAMPING = 1e3
CONVERGED_DECREASE = 1e-10


def _sum_matrix(point_index, n_points: int):
    """Sparse (points x samples) matrix of ones where a sample is the point's: its product with a sample array sums it per point."""
    return sparse.csr_matrix((np.ones(len(point_index)), (point_index, np.arange(len(point_index)))), shape=(n_points, len(point_index)))


def refine_points(point_index, rotations, view_cam, brightness, normals, albedo, minnaert_k, light_dir_cam, *, n_iterations=15, min_observations=8, max_tilt_deg=45.0, normal_prior_deg=10.0, fit_albedo_k=True, noise_var=None, axis=None):
    """Per-point LM on (normal, albedo, k) with the light fixed; returns new arrays and the refined mask.

    ``rotations`` (n_obs, 3, 3) are the body-to-camera rotations of each
    observation's image; normals are in the reconstruction (body) frame.
    The starting normal acts as a Gaussian prior of ``normal_prior_deg`` per
    axis, weighed against the brightness residuals' own scatter (a MAP
    estimate: brightness errors from mispositioned samples otherwise tilt
    normals freely); a normal may turn at most ``max_tilt_deg``. With an
    ``axis`` a normal only turns about it (its latitude about the axis stays).

    Every point's system is its own: the work is done on the points with
    enough samples only, and every sum over each point's samples is one
    sparse product.
    """
    n_points = len(normals)
    counts = np.bincount(point_index, minlength=n_points)
    active = (counts >= max(min_observations, 1)) & np.isfinite(albedo) & np.isfinite(minnaert_k)
    out_normals, out_albedo, out_k = normals.copy(), albedo.copy(), minnaert_k.copy()
    if not active.any():
        return out_normals, out_albedo, out_k, active
    # The active points' samples, grouped by point; p numbers the active points 0..m-1.
    rows = np.flatnonzero(active[point_index])
    rows = rows[np.argsort(point_index[rows], kind="stable")]
    p = (np.cumsum(active) - 1)[point_index[rows]]
    per_point = _sum_matrix(p, int(active.sum()))
    rot, brightness = rotations[rows], brightness[rows]
    light_b = np.einsum("nji,j->ni", rot, light_dir_cam)  # R^T l
    view_b = np.einsum("nji,nj->ni", rot, view_cam[rows])  # R^T v
    start = normals[active]
    normals, albedo, minnaert_k = start.copy(), albedo[active].copy(), minnaert_k[active].copy()
    # The parameters fitted: the normal's two tangent turns (one about an axis), then albedo and k.
    free = [0] + ([] if axis is not None else [1]) + ([2, 3] if fit_albedo_k else [])
    pairs = [(a, b) for a in range(len(free)) for b in range(a, len(free))]  # J^T J's upper triangle

    def evaluate(n, a, k, st):
        f, cos_i, cos_o = _model(n[p], light_b, view_b, a[p], k[p])
        cost = per_point @ (f - brightness) ** 2 + prior_weight * np.sum((n - st) ** 2, axis=1)
        return cost, f, cos_i, cos_o

    if noise_var is None:
        f0, _, _ = _model(normals[p], light_b, view_b, albedo[p], minnaert_k[p])
        noise_var = np.median((f0 - brightness) ** 2) / 0.455  # robust variance of the residuals
    prior_weight = noise_var / np.radians(normal_prior_deg) ** 2

    # The points still iterating (ids into the arrays above) and their state; the working set drops the
    # converged points (FROZEN_DAMPING, CONVERGED_DECREASE) when they are a fifth of it.
    ids = np.arange(len(start))
    n_, a_, k_, st_, damping = normals, albedo, minnaert_k, start, np.full(len(start), 1e-3)
    cost, f, cos_i, cos_o = evaluate(n_, a_, k_, st_)
    for _ in range(n_iterations):
        if axis is None:
            e1, e2 = _tangent_basis(n_)
        else:  # the derivative of a turn about the axis; no second direction
            e1, e2 = np.cross(axis, n_), np.zeros_like(n_)
        k = k_[p]
        d_normal = f[:, None] * (k[:, None] / cos_i[:, None] * light_b + (k[:, None] - 1.0) / cos_o[:, None] * view_b)
        columns = {
            0: lambda: np.einsum("ij,ij->i", d_normal, e1[p]),
            1: lambda: np.einsum("ij,ij->i", d_normal, e2[p]),
            2: lambda: f / a_[p],
            3: lambda: f * (np.log(cos_i) + np.log(cos_o)),
        }
        jac = [columns[c]() for c in free]
        residual = f - brightness
        # Each product summed per point on its own: no (samples x products) array is made, and each sum adds the same terms in the same order.
        products = [jac[a] * jac[b] for a, b in pairs] + [column * residual for column in jac]
        sums = np.column_stack([per_point @ product for product in products])
        jtj = np.empty((len(ids), len(free), len(free)))
        for column, (a, b) in enumerate(pairs):
            jtj[:, a, b] = jtj[:, b, a] = sums[:, column]
        jtr = sums[:, len(pairs):]
        # The prior on the normal, linearised in the tangent plane of the current normal.
        offset = n_ - st_
        for column, direction in ((0, e1), (1, e2)):
            if column in free:
                jtr[:, free.index(column)] += prior_weight * np.einsum("ij,ij->i", offset, direction)
                jtj[:, free.index(column), free.index(column)] += prior_weight * np.einsum("ij,ij->i", direction, direction)
        diag = np.einsum("nii->ni", jtj)
        system = jtj + (damping[:, None] * np.maximum(diag, 1e-12))[:, :, None] * np.eye(len(free))
        step = np.zeros((len(ids), 4))
        step[:, free] = -np.linalg.solve(system, jtr[:, :, None])[:, :, 0]
        if axis is None:
            trial_normals = n_ + step[:, [0]] * e1 + step[:, [1]] * e2
            trial_normals /= np.linalg.norm(trial_normals, axis=1, keepdims=True)
        else:
            trial_normals = _turn(n_, axis, step[:, 0])
        trial_albedo = np.maximum(a_ + step[:, 2], 1e-4)
        trial_k = np.clip(k_ + step[:, 3], 0.05, 2.0)
        tilt_ok = np.einsum("ij,ij->i", trial_normals, st_) >= np.cos(np.radians(max_tilt_deg))
        trial_cost, trial_f, trial_cos_i, trial_cos_o = evaluate(trial_normals, trial_albedo, trial_k, st_)
        better = tilt_ok & (trial_cost < cost)
        settled = better & (cost - trial_cost <= CONVERGED_DECREASE * cost)
        n_[better], a_[better], k_[better], cost[better] = trial_normals[better], trial_albedo[better], trial_k[better], trial_cost[better]
        moved = better[p]
        f, cos_i, cos_o = np.where(moved, trial_f, f), np.where(moved, trial_cos_i, cos_i), np.where(moved, trial_cos_o, cos_o)
        damping = np.where(better, damping / 3.0, damping * 4.0)
        going = (damping < FROZEN_DAMPING) & ~settled
        if np.count_nonzero(going) < 0.8 * len(ids):  # drop the converged points (their state is written back first)
            normals[ids], albedo[ids], minnaert_k[ids] = n_, a_, k_
            ids, kept = ids[going], going[p]
            n_, a_, k_, st_, damping, cost = n_[going], a_[going], k_[going], st_[going], damping[going], cost[going]
            p, light_b, view_b, brightness = (np.cumsum(going) - 1)[p[kept]], light_b[kept], view_b[kept], brightness[kept]
            f, cos_i, cos_o = f[kept], cos_i[kept], cos_o[kept]
            per_point = _sum_matrix(p, len(ids))
    normals[ids], albedo[ids], minnaert_k[ids] = n_, a_, k_
    out_normals[active], out_albedo[active], out_k[active] = normals, albedo, minnaert_k
    return out_normals, out_albedo, out_k, active


def relative_residuals(point_index, rotations, view_cam, brightness, normals, albedo, minnaert_k, light_dir_cam) -> np.ndarray:
    """Per point: RMS of (model - observed) over its observations, relative to its mean brightness (inf without any)."""
    n_points = len(normals)
    light_b = np.einsum("nji,j->ni", rotations, light_dir_cam)
    view_b = np.einsum("nji,nj->ni", rotations, view_cam)
    model, _, _ = _model(normals[point_index], light_b, view_b, albedo[point_index], minnaert_k[point_index])
    counts = np.bincount(point_index, minlength=n_points)
    squares = np.bincount(point_index, weights=(model - brightness) ** 2, minlength=n_points)
    total = np.bincount(point_index, weights=brightness, minlength=n_points)
    with np.errstate(divide="ignore", invalid="ignore"):
        residual = np.sqrt(squares / counts) / (total / counts)
    return np.where(counts > 0, residual, np.inf)


def one_albedo(observations: Observations) -> Observations:
    """The same samples as those of one point: a fit to them has one albedo for the whole body (each row keeps its own normal)."""
    return Observations(
        point_index=np.zeros(observations.n_obs, dtype=int), normal_cam=observations.normal_cam, view_cam=observations.view_cam,
        brightness=observations.brightness, n_points=1,
    )


@dataclass
class PureSampleCloud:
    """The refined cloud: accepted points with fitted normals and their pure samples."""

    points: np.ndarray  # (M, 3) reconstruction frame, each at its chosen offset
    normals: np.ndarray  # (M, 3) fitted normals, reconstruction frame
    surface_normals: np.ndarray  # (M, 3) the surface's normals there, where the fit started
    observations: Observations  # their pure samples (camera frames)
    image_index: np.ndarray  # (n_obs,) the image of each observation
    offset_px: np.ndarray  # (M,) chosen offset along the surface normal, in pixels
    residual: np.ndarray  # (M,) relative RMS residual of the one-facet fit (with a sensor: over its noise-limited value)
    n_candidates: int
    light_dir_cam: np.ndarray  # the light the normals were fitted under
    refined_light_dir_cam: np.ndarray  # the light fitted to the pure samples: one k for the body (fit_pooled_k), or anchored_light's
    refined_minnaert_k: float  # that fit's k for the body
    image_gains: np.ndarray | None = None  # per image, the calibration gains the light step divided out (anchored_light); None: none
    normals_tilt_freely: bool = False  # the normals were fitted about both axes (no spin axis: views or light out of the ring's plane)

    def over_gains(self, gains) -> "PureSampleCloud":
        """The same cloud with each sample's brightness divided by its image's gain (``gains``: per image index), the
        gains kept in ``image_gains`` (times any divided out before)."""
        gains = np.asarray(gains, float)
        obs = self.observations
        divided = Observations(obs.point_index, obs.normal_cam, obs.view_cam, obs.brightness / gains[self.image_index], obs.n_points)
        return replace(self, observations=divided, image_gains=gains if self.image_gains is None else self.image_gains * gains)

    def save(self, path) -> None:
        """One .npz with the arrays."""
        obs = self.observations
        files.savez(
            path, points=self.points, normals=self.normals, surface_normals=self.surface_normals, point_index=obs.point_index,
            normal_cam=obs.normal_cam, view_cam=obs.view_cam, brightness=obs.brightness, image_index=self.image_index,
            offset_px=self.offset_px, residual=self.residual, n_candidates=self.n_candidates, light_dir_cam=self.light_dir_cam,
            refined_light_dir_cam=self.refined_light_dir_cam, refined_minnaert_k=self.refined_minnaert_k, normals_tilt_freely=self.normals_tilt_freely,
            **({} if self.image_gains is None else {"image_gains": self.image_gains}),
        )

    @classmethod
    def load(cls, path) -> "PureSampleCloud":
        with np.load(path) as data:
            if "normals_tilt_freely" not in data.files:
                raise ValueError(
                    f"{path}: a refined cloud written by an older version of the workflow (it does not say whether its normals "
                    "tilted freely); refine it again: snakemake --forcerun refine_cloud"
                )
            observations = Observations(
                point_index=data["point_index"], normal_cam=data["normal_cam"], view_cam=data["view_cam"], brightness=data["brightness"],
                n_points=len(data["points"]),
            )
            return cls(
                data["points"], data["normals"], data["surface_normals"], observations, data["image_index"], data["offset_px"], data["residual"],
                int(data["n_candidates"]), data["light_dir_cam"], data["refined_light_dir_cam"], float(data["refined_minnaert_k"]),
                data["image_gains"] if "image_gains" in data.files else None, bool(data["normals_tilt_freely"]),
            )


def _fit_candidates(points, normals, pair_point, pair_image, poses, intrinsics, images, light_dir_cam, albedo, minnaert_k, purity_tolerance, min_observations, normal_prior_deg, axis, max_residual, gain_sigma=0.0):
    """One offset: pure samples of every candidate and the one-facet fit to them; (score, fitted normals).

    The score is the relative RMS residual, or with a statistical purity test
    (``purity.PurityTest``) that residual over the largest the sensor's
    noise explains (:func:`noise_limited_residual`, with ``max_residual`` and
    the images' calibration scatter ``gain_sigma`` added in quadrature); a
    candidate is accepted at a score of ``max_residual`` or less, resp. 1 or less.
    """
    statistical = callable(purity_tolerance)
    brightness, points_cam, inside = cloud_lib.sample_images(points[pair_point], pair_image, poses, intrinsics, images, purity_tolerance)
    keep = inside & (brightness > 0)
    counts = np.bincount(pair_point[keep], minlength=len(points))
    keep &= counts[pair_point] >= min_observations
    enough = counts >= min_observations
    p = pair_point[keep]
    rotations = cloud_lib.rotations_of(poses, pair_image[keep])
    view_cam = -points_cam[keep] / np.linalg.norm(points_cam[keep], axis=1, keepdims=True)
    start_albedo = np.where(enough, albedo, np.nan)
    start_k = np.where(enough, minnaert_k, np.nan)
    # The samples' own scatter is the purity tolerance (or the sensor's noise): the prior weighs against that, not against the starting misfit.
    if statistical:
        noise_var = float(purity_tolerance.sample_variance(np.median(brightness[keep]))) if keep.any() else 1.0
    else:
        noise_var = (purity_tolerance * np.median(brightness[keep])) ** 2 if keep.any() else 1.0
    fitted_normals, fitted_albedo, fitted_k, active = refine_points(
        p, rotations, view_cam, brightness[keep], normals, start_albedo, start_k, light_dir_cam,
        n_iterations=30, min_observations=min_observations, normal_prior_deg=normal_prior_deg, fit_albedo_k=True, noise_var=noise_var, axis=axis,
    )
    residual = relative_residuals(p, rotations, view_cam, brightness[keep], fitted_normals, fitted_albedo, fitted_k, light_dir_cam)
    if statistical:  # only the fitted points have a limit to score against; the others score inf
        limit = noise_limited_residual(p, brightness[keep], len(points), purity_tolerance, float(np.hypot(max_residual, gain_sigma)))
        residual = np.divide(residual, limit, out=np.full_like(residual, np.inf), where=active)
    residual[~active] = np.inf
    return residual, fitted_normals


#: Parameters of a one-facet fit (the normal's turn, albedo, k): the residual's degrees of freedom are the samples less these.
ONE_FACET_PARAMETERS = 3
#: Probability that a candidate whose samples one facet explains is refused by the noise-limited residual test.
RESIDUAL_SIGNIFICANCE = 0.01


def noise_limited_residual(point_index, brightness, n_points: int, purity_test, floor: float) -> np.ndarray:
    """Per point, the largest relative RMS residual of a one-facet fit that the sensor's noise explains.

    For ``n`` samples of one facet, ``n * rms^2 / sigma^2`` follows a
    chi-square law with ``n - 3`` degrees of freedom (``sigma^2``: one pure
    sample's noise variance at the point's mean brightness,
    ``purity_test.sample_variance``); the limit is its ``1 -
    RESIDUAL_SIGNIFICANCE`` quantile, relative to the mean brightness, with
    ``floor`` (the noise-free setting's ``max_residual``) added in
    quadrature for the model's own scatter.
    """
    counts = np.bincount(point_index, minlength=n_points)
    mean = np.bincount(point_index, weights=brightness, minlength=n_points) / np.maximum(counts, 1)
    dof = np.maximum(counts - ONE_FACET_PARAMETERS, 1)
    quantile = chdtri(dof, RESIDUAL_SIGNIFICANCE)
    with np.errstate(divide="ignore", invalid="ignore"):
        relative_var = purity_test.sample_variance(mean) / mean**2
        limit = np.sqrt(relative_var * quantile / np.maximum(counts, 1) + floor**2)
    return np.where(counts > 0, limit, np.inf)


def refine_by_pure_samples(
    surface, poses: dict, intrinsics: Intrinsics, images: list[np.ndarray], light_dir_cam, albedo: float, minnaert_k: float, *,
    n_candidates: int = 60000, max_offset_px: float = 2.0, offset_steps: int = 11, purity_tolerance=1e-3,
    max_residual: float = 1e-3, min_observations: int = 6, min_cos_emission: float = 0.2, normal_prior_deg: float = 30.0, seed: int = 0, axis=None,
    gain_sigma: float = 0.0,
) -> PureSampleCloud:
    """Points on ``surface`` moved and turned until their samples are pure and one facet explains them (module docstring).

    ``surface``: (vertices, triangles) in the reconstruction frame, the frame
    of ``poses`` (body-to-camera matrices by image index). ``light_dir_cam``,
    ``albedo`` and ``minnaert_k``: the estimator's light and the set's
    typical albedo and k, the starting point of each one-facet fit. Offsets
    are in pixels (the candidate's footprint in the images that see it), so
    the search is the same in any similarity frame. ``axis``: the spin axis
    the normals turn about (``spin_axis``); None lets them tilt freely.
    ``purity_tolerance``: the relative tolerance of noise-free images, or a
    ``purity.PurityTest`` of the images' sensor; then a candidate is
    accepted when its residual is what that noise explains, with
    ``max_residual`` added for the model's own scatter
    (:func:`noise_limited_residual`) and ``gain_sigma`` for the images'
    calibration error: each of a point's samples comes from another image,
    so an unknown gain per image of that one-sigma scatters them by as much
    (without it, the candidates kept are those whose fit absorbed the gains,
    and their normals and k carry them; docs/table2.md, sections 6 and 11).
    """
    import open3d as o3d

    vertices, triangles = surface
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    mesh.compute_vertex_normals()
    o3d.utility.random.seed(seed)
    sampled = mesh.sample_points_uniformly(number_of_points=n_candidates)
    points = np.asarray(sampled.points)
    normals = np.asarray(sampled.normals)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    candidates = cloud_lib.OrientedCloud(points, normals, np.zeros(len(points), int))
    pair_point, pair_image = cloud_lib.visible_pairs(candidates, poses, min_cos_emission, cloud_lib.default_occlusion_tolerance(points), surface)
    # A candidate's footprint: its mean depth over the cameras that see it, over the focal length.
    pair_poses = cloud_lib.poses_of(poses, pair_image)
    depth = np.einsum("nj,nj->n", pair_poses[:, 2, :3], points[pair_point]) + pair_poses[:, 2, 3]
    counts = np.bincount(pair_point, minlength=len(points))
    footprint = np.bincount(pair_point, weights=depth, minlength=len(points)) / np.maximum(counts, 1) / intrinsics.focal_px

    best_residual = np.full(len(points), np.inf)
    best_offset = np.zeros(len(points))
    best_normals = normals.copy()
    for offset_px in np.linspace(-max_offset_px, max_offset_px, offset_steps) if offset_steps > 1 else [0.0]:
        shifted = points + (offset_px * footprint)[:, None] * normals
        residual, fitted_normals = _fit_candidates(
            shifted, normals, pair_point, pair_image, poses, intrinsics, images, light_dir_cam, albedo, minnaert_k,
            purity_tolerance, min_observations, normal_prior_deg, axis, max_residual, gain_sigma,
        )
        better = residual < best_residual
        best_residual[better], best_offset[better], best_normals[better] = residual[better], offset_px, fitted_normals[better]
    accepted = np.flatnonzero(best_residual <= (1.0 if callable(purity_tolerance) else max_residual))
    log.info(
        "pure-sample refinement: %d candidates, %d with >= %d pure samples at some offset, %d accepted (%s)",
        len(points), int(np.isfinite(best_residual).sum()), min_observations, len(accepted),
        "residual within what the sensor's noise explains" if callable(purity_tolerance) else f"relative residual <= {max_residual:g}",
    )
    surface_normals = normals[accepted]
    points = points[accepted] + (best_offset[accepted] * footprint[accepted])[:, None] * surface_normals
    normals = best_normals[accepted]
    in_accepted = np.full(len(candidates.points), -1)
    in_accepted[accepted] = np.arange(len(accepted))
    rows = in_accepted[pair_point] >= 0
    point_index, image_index = in_accepted[pair_point[rows]], pair_image[rows]
    brightness, points_cam, inside = cloud_lib.sample_images(points[point_index], image_index, poses, intrinsics, images, purity_tolerance)
    normal_cam = cloud_lib.in_cameras(normals[point_index], image_index, poses, translate=False)
    view_cam = -points_cam / np.linalg.norm(points_cam, axis=1, keepdims=True)
    # The fitted normal may turn away from a camera that saw the surface's: that sample goes.
    keep = inside & (brightness > 0) & (np.einsum("ij,ij->i", normal_cam, view_cam) > 0.05)
    counts = np.bincount(point_index[keep], minlength=len(points))
    keep &= counts[point_index] >= min_observations
    observations = Observations(
        point_index=point_index[keep], normal_cam=normal_cam[keep], view_cam=view_cam[keep], brightness=brightness[keep], n_points=len(points),
    )
    # The light again, from the pure samples, with one k for the body (step 4, module docstring); with the
    # normals free to tilt, one albedo for the body too.
    refined_light, refined_k = np.full(3, np.nan), np.nan
    if observations.n_obs >= 3 + np.count_nonzero(observations.observations_per_point):  # an albedo per point, one k, the light
        light_samples = observations if axis is not None else one_albedo(observations)
        pooled = fit_pooled_k(light_samples, light_dir_cam, minnaert_k, min_observations=min_observations if axis is not None else 1)
        refined_light, refined_k = pooled.light_dir_cam, float(np.nanmedian(pooled.minnaert_k))
        if axis is None:  # one albedo pins the elevation; the azimuth stays the start's (module docstring)
            refined_light = keep_azimuth(refined_light, light_dir_cam, ring_axis_cam(poses))
        log.info(
            "light from the pure samples with one k (%.4f)%s: %.3f deg from the light the normals were fitted under%s", refined_k,
            "" if axis is not None else " and one albedo (normals free to tilt)", float(angle_between_deg(refined_light, light_dir_cam)),
            "" if axis is not None else f" (its elevation; the azimuth kept, {float(angle_between_deg(pooled.light_dir_cam, refined_light)):.3f} deg from one albedo's)",
        )
    return PureSampleCloud(
        points, normals, surface_normals, observations, image_index[keep], best_offset[accepted], best_residual[accepted], len(candidates.points),
        np.asarray(light_dir_cam, dtype=float), refined_light, refined_k, normals_tilt_freely=axis is None,
    )



#: How many times the Table 2 path refines a cloud under a sensor with per-image gains
#: (``experiments.table2``): a second pass runs on the images divided by the first pass's gains
#: (:func:`anchored_light`), its residual test then the sensor's alone; the first pass's residual test allows
#: the gains' scatter (``refine_by_pure_samples``'s ``gain_sigma``). Chosen on the tuning grid (config/tuning.yaml,
#: its `amica` rows), between 1 and 2 (docs/table2.md, section 12).
CALIBRATION_PASSES = 2
#: Where the normals tilt freely (no spin axis to turn about; the `oblique` condition) the refinement runs again from
#: its light step's light, up to this many passes in all, until that light is within :data:`FREE_TILT_SETTLED_DEG` of
#: the light the pass's normals were fitted under. Each pass's normals follow the light they were fitted under, and
#: the one-albedo step takes part of its elevation error off (a third to nine tenths of it in the first pass). Chosen on
#: config/conditions_geometry.yaml's four `oblique` rows (albedo 0.6; none of the paper's sets): 1, 2, 3 and 4 passes
#: put 1, 2, 3 and 3 of them within all bounds (docs/table2.md, section 12).
FREE_TILT_PASSES = 4
#: See :data:`FREE_TILT_PASSES`: on those rows the light moved 0.02 to 0.04 deg in a third pass where it had settled
#: and 0.4 where it had not; any value from 0.05 to 0.34 deg stops the same passes there.
FREE_TILT_SETTLED_DEG = 0.25


#: The share of ``reconstruction.refine_candidates`` the first of two passes draws: it only finds the gains, and a
#: third of the candidates keeps the refinement's runtime within the workflow's budget (docs/table2.md, section 12).
FIRST_PASS_CANDIDATE_SHARE = 1 / 3

#: The standard deviation of the prior that holds each point's k to the body's in :func:`anchored_light`.
#: Chosen on the tuning grid (config/tuning.yaml, its `amica` rows), among 0.0125, 0.025, 0.05, 0.1 and 0.2
#: with one refinement pass, and checked again against 0.0125 and 0.05 with :data:`CALIBRATION_PASSES`
#: (docs/table2.md, section 12).
K_PRIOR_SD = 0.025


def refine_until_settled(pure: PureSampleCloud, again, max_passes: int, settled_deg: float) -> PureSampleCloud:
    """``pure`` refined once more (``again(pure)``, a new pass from its light step's light) while that step moved the
    light at least ``settled_deg`` from the light the pass's normals were fitted under, up to ``max_passes`` passes in
    all (``pure`` being the first)."""
    for passes in range(2, max_passes + 1):
        moved = float(angle_between_deg(pure.refined_light_dir_cam, pure.light_dir_cam))
        if moved < settled_deg:
            break
        pure = again(pure)
        log.info("pass %d from the previous light step's light (it had moved the light %.3f deg): %d points kept", passes, moved, len(pure.points))
    return pure


def common_turn_deg(normals, surface_normals, axis) -> float:
    """The median signed turn (deg, right-handed about ``axis``) from each surface normal to its fitted normal."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return float(np.degrees(np.median(turns_about(normals, surface_normals, axis))))


#: The prior standard deviation (degrees) of the light's elevation error that :func:`anchored_light` takes
#: off the normals' turns: the error their pattern shows is shrunk by ``prior^2 / (prior^2 + se^2)``
#: (``se``: that measurement's standard error; 0 takes nothing off). Chosen on the tuning grid
#: (config/tuning.yaml, its `amica` rows): among 0, 0.25, 0.5, 1, 2 and none (no shrinking) with one
#: refinement pass (0.25 and 0.5 tied), then among 0, 0.25 and 0.5 with the two passes of
#: :data:`CALIBRATION_PASSES`, whose many more points measure the pattern with a far smaller ``se``
#: (docs/table2.md, section 12).
ELEVATION_PRIOR_DEG = 0.25


def elevation_turn_pattern(obs: Observations, axis_cam, light_dir_cam, minnaert_k: float, weights) -> np.ndarray:
    """Per point: the turn about the spin axis (radians) its one-facet fit takes up per radian of the light's elevation error.

    A point's fit moves its normal's turn, albedo and k to explain its
    samples under the light it is given. A light raised by ``e`` out of the
    plane of the views (towards the axis) adds ``e * g_e`` to each log
    brightness; the fit takes up the part of it that a turn can explain once
    the albedo and k have taken theirs: the coefficient of the turn's
    derivative ``g_t`` in the weighted regression of ``g_e`` on ``[1, g_k,
    g_t]``, negated. ``axis_cam``: the spin axis in each row's camera frame;
    ``weights``: each row's weight (inverse variance of its log brightness).
    NaN where a point's rows cannot separate the three.
    """
    light = np.asarray(light_dir_cam, dtype=float)
    normal, view = obs.normal_cam, obs.view_cam
    cos_i = np.clip(normal @ light, 1e-3, None)
    cos_o = np.clip(np.einsum("ij,ij->i", normal, view), 1e-3, None)
    turned = np.cross(axis_cam, normal)  # d(normal)/d(turn)
    g_turn = minnaert_k * (turned @ light) / cos_i + (minnaert_k - 1.0) * np.einsum("ij,ij->i", turned, view) / cos_o
    raise_dir = axis_cam - (axis_cam @ light)[:, None] * light
    raise_dir /= np.linalg.norm(raise_dir, axis=1, keepdims=True)
    g_elev = minnaert_k * np.einsum("ij,ij->i", normal, raise_dir) / cos_i
    design = np.stack([np.ones_like(g_turn), np.log(cos_i) + np.log(cos_o), g_turn], axis=1)
    # Each point's 3x3 weighted normal equations, summed over its rows, solved in one batched call.
    gram = np.zeros((obs.n_points, 3, 3))
    np.add.at(gram, obs.point_index, weights[:, None, None] * design[:, :, None] * design[:, None, :])
    rhs = np.zeros((obs.n_points, 3))
    np.add.at(rhs, obs.point_index, (weights * g_elev)[:, None] * design)
    pattern = np.full(obs.n_points, np.nan)
    solvable = np.linalg.cond(gram) < 1e10
    pattern[solvable] = -np.linalg.solve(gram[solvable], rhs[solvable][:, :, None])[:, 2, 0]
    return pattern


def elevation_in_turns(turns, pattern) -> tuple[float, float, float]:
    """The light's elevation error (radians) that the turns' pattern shows, its standard error, and the common turn.

    ``turns``: each point's turn from its surface normal to its fitted
    normal; ``pattern``: :func:`elevation_turn_pattern`. A robust straight-
    line fit of the turns on the pattern (``scipy.optimize.least_squares``,
    soft-L1 loss at the turns' robust spread): the slope is the elevation
    error the turns absorbed, the intercept the common turn. Returns
    ``(elevation, standard_error, common_turn)``; no elevation (0, inf) from
    fewer than 10 points or a pattern with no spread.
    """
    use = np.isfinite(pattern) & np.isfinite(turns)
    x, y = pattern[use], turns[use]
    if x.size < 10 or np.ptp(x) == 0:
        return 0.0, np.inf, float(np.median(y)) if y.size else 0.0
    scale = 1.4826 * np.median(np.abs(y - np.median(y)))
    slope, intercept = np.polyfit(x, y, 1)  # the plain fit, where the robust one starts
    fit = least_squares(lambda b: b[0] + b[1] * x - y, [intercept, slope], loss="soft_l1", f_scale=max(scale, 1e-6), x_scale="jac")
    residual = y - fit.x[0] - fit.x[1] * x
    spread = 1.4826 * np.median(np.abs(residual - np.median(residual)))
    return float(fit.x[1]), float(spread / np.sqrt(np.sum((x - x.mean()) ** 2))), float(fit.x[0])


def turns_about(normals, surface_normals, axis) -> np.ndarray:
    """Each point's signed turn (radians, right-handed about ``axis``) from its surface normal to its normal."""
    fitted = normals - np.outer(normals @ axis, axis)
    start = surface_normals - np.outer(surface_normals @ axis, axis)
    return np.arctan2(np.cross(start, fitted) @ axis, np.einsum("ij,ij->i", start, fitted))


def anchored_light(pure: PureSampleCloud, poses: dict, axis, relative_sd, *, gain_sigma: float, n_images: int, min_observations: int) -> PureSampleCloud:
    """The refined cloud with its normals' common turn and elevation pattern taken off, and the light, k and gains fitted under a sensor.

    Turning every normal and the light together about the spin axis changes
    the brightness only through the weak ``cos_o**(k - 1)`` (section 7 of
    docs/table2.md): the refinement's fitted normals keep whatever common turn
    the light they were fitted under gave them. Their surface normals, from
    the cloud's geometry, fix it: the median turn from the surface normals to
    the fitted ones (:func:`common_turn_deg`) is taken off every normal. Then
    the light, each point's albedo and k (held to the body's by
    :data:`K_PRIOR_SD`) and each image's gain (prior ``gain_sigma``) are fitted
    together (``estimation.hierarchical.fit_light_k_prior``, each sample
    weighted by ``relative_sd(brightness)``, its noise over its brightness).

    The starting light's elevation hides in the normals too, not in one
    common turn but in a pattern of turns (:func:`elevation_turn_pattern`:
    how far each point's fit turns per radian of elevation error). The turns
    from the surface normals are fitted on that pattern
    (:func:`elevation_in_turns`); the elevation error it shows, shrunk by its
    standard error against :data:`ELEVATION_PRIOR_DEG`, is taken off the
    normals in that pattern, and the light, k and gains are fitted again. The
    samples are returned with the gains divided out, and the light and body
    k replace the one-k fit's. ``axis``: the spin axis (``turn_axis``).
    """
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    turn = common_turn_deg(pure.normals, pure.surface_normals, axis)
    normals = Rotation.from_rotvec(-np.radians(turn) * axis).apply(pure.normals)
    obs = pure.observations
    rotations = cloud_lib.rotations_of(poses, pure.image_index)

    def fit_under(normals):
        """The light, k and gains fitted with ``normals`` held; the samples used, with the gains divided out; which rows they are."""
        normal_cam = np.einsum("nij,nj->ni", rotations, normals[obs.point_index])
        keep = np.einsum("ij,ij->i", normal_cam, obs.view_cam) > 0.05
        held = Observations(obs.point_index[keep], normal_cam[keep], obs.view_cam[keep], obs.brightness[keep], obs.n_points)
        image_index = pure.image_index[keep]
        fit = fit_light_k_prior(
            held, image_index, pure.refined_light_dir_cam, pure.refined_minnaert_k, relative_sd=relative_sd(held.brightness),
            k_prior_sd=K_PRIOR_SD, gain_sigma=gain_sigma, n_images=n_images, min_observations=min_observations,
        )
        corrected = Observations(held.point_index, held.normal_cam, held.view_cam, held.brightness / fit.gains[image_index], held.n_points)
        return fit, corrected, keep

    first, corrected, keep = fit_under(normals)
    pattern = elevation_turn_pattern(corrected, rotations[keep] @ axis, first.light_dir_cam, first.body_k, 1.0 / relative_sd(corrected.brightness) ** 2)
    elevation, standard_error, _ = elevation_in_turns(turns_about(normals, pure.surface_normals, axis), pattern)
    prior = np.radians(ELEVATION_PRIOR_DEG)
    taken_off = elevation if np.isinf(prior) else elevation * prior**2 / (prior**2 + standard_error**2)
    normals = Rotation.from_rotvec(-(np.nan_to_num(pattern) * taken_off)[:, None] * axis).apply(normals)
    fit, corrected, keep = fit_under(normals)
    log.info(
        "light step under the sensor: the normals' common turn %.2f deg taken off; their turns show an elevation error of %.2f +- %.2f deg, "
        "%.2f of it taken off; light %.3f deg from the one-k light (%.3f before the elevation), body k %.4f, gains %.4f to %.4f "
        "(k prior %g, gain prior %g, elevation prior %g deg)", turn, np.degrees(elevation), np.degrees(standard_error), np.degrees(taken_off),
        float(angle_between_deg(fit.light_dir_cam, pure.refined_light_dir_cam)), float(angle_between_deg(first.light_dir_cam, pure.refined_light_dir_cam)),
        fit.body_k, float(np.min(fit.gains)), float(np.max(fit.gains)), K_PRIOR_SD, gain_sigma, ELEVATION_PRIOR_DEG,
    )
    return replace(
        pure, normals=normals, observations=corrected, image_index=pure.image_index[keep], refined_light_dir_cam=fit.light_dir_cam,
        refined_minnaert_k=fit.body_k, image_gains=fit.gains,
    )
