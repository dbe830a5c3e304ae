"""Estimate the light direction, albedo and Minnaert k from sampled brightness.

This is the ``fit`` stage of the workflow. ``observe`` hands over, for every
surface point and every image that sees it, the point's unit normal and the
unit vector towards the camera (both in that image's camera frame) and the
brightness sampled there; this module turns that into estimates:

- :func:`fit_koizumi_lm`: the paper's estimator. One global light direction
  ``l`` plus an albedo and a Minnaert k per point, fitted jointly by
  Levenberg-Marquardt to the brightness residuals
  ``b - albedo * cos_i**k * cos_o**(k - 1)``.
- :func:`fit_iwano_linear`: Iwano's baseline. One albedo for the whole body
  and a known k; the substitution ``s = albedo**(1/k) * l`` makes the problem
  linear in ``s``.

Frames and units follow the package conventions (``asteroid_photometry``):
camera frame with +z along the optical axis, ``light_dir_cam`` the unit
vector towards the Sun, angles in radians unless a name ends in ``_deg``.

The light is parameterised by gnomonic (tangent-plane) coordinates about the
direction towards the camera, ``-z``: ``l = normalize((a, b, -1))``. The light
in this problem is always close to ``-z`` (the paper's sets have light angles
of 0 and 10 degrees), and unlike spherical angles this chart is smooth and
well-conditioned at a light angle of exactly 0.

:func:`synthetic_observations` builds noiseless or noisy observations of a
turning body with a known truth, for the tests and the benchmarks.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np
import scipy.optimize
import scipy.sparse

__all__ = [
    "Observations",
    "FitResult",
    "KoizumiProblem",
    "light_from_tangent",
    "tangent_from_light",
    "light_angle_deg",
    "angle_between_deg",
    "minnaert_brightness",
    "fit_iwano_linear",
    "fit_koizumi_lm",
    "fit_pooled_k",
    "solve_arrow_system",
    "arrow_covariance",
    "light_std_deg",
    "initial_albedo_and_k",
    "profile_cost",
    "search_light",
    "synthetic_observations",
]

UNIT_TOLERANCE = 1e-6
# Floor of cos_i inside the LM residual: a trial step may tilt the light so
# that some normals face away from it; the floor keeps log and pow finite.
# At the truth every observation must have cos_i > 0 (observe keeps only lit
# ones, cos_i > min_cos_incidence), so the floor is inactive at convergence.
COS_INCIDENCE_FLOOR = 1e-6
# Bounds of k in the log-linear initialisation.
INIT_K_RANGE = (0.05, 1.5)


# --------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------


def _frozen_array(value, dtype, name):
    try:
        array = np.array(value, dtype=dtype, copy=True)
    except (TypeError, ValueError) as error:
        raise ValueError(f"Observations.{name} cannot be converted to {np.dtype(dtype).name}: {error}") from None
    array.flags.writeable = False
    return array


@dataclasses.dataclass(frozen=True, eq=False)
class Observations:
    """Brightness observations of surface points, one row per (point, image) pair.

    Attributes
    ----------
    point_index : int64 array (n_obs,)
        Which point (0 .. n_points - 1) the row observes.
    normal_cam : float64 array (n_obs, 3)
        The point's unit normal in the camera frame of the image.
    view_cam : float64 array (n_obs, 3)
        Unit vector from the point to the camera centre, camera frame.
    brightness : float64 array (n_obs,)
        The observed brightness ``b`` (linear, the Minnaert radiance).
    n_points : int
        Number of points; points without rows are allowed (their estimates
        are NaN).

    The arrays are copied and made read-only. The constructor raises
    ``ValueError`` on wrong shapes, non-finite values, normals or view
    vectors that are not unit length (within 1e-6), rows whose normal faces
    away from the camera (``cos_emission <= 0``) and out-of-range indices.
    """

    point_index: np.ndarray
    normal_cam: np.ndarray
    view_cam: np.ndarray
    brightness: np.ndarray
    n_points: int

    def __post_init__(self):
        if isinstance(self.n_points, (bool, np.bool_)) or not isinstance(self.n_points, (int, np.integer)):
            raise ValueError(f"Observations.n_points must be an int, got {type(self.n_points).__name__}")
        if self.n_points < 0:
            raise ValueError(f"Observations.n_points must be >= 0, got {self.n_points}")
        object.__setattr__(self, "n_points", int(self.n_points))

        raw_index = np.asarray(self.point_index)
        if raw_index.size and not np.issubdtype(raw_index.dtype, np.integer):
            raise ValueError(f"Observations.point_index must be integers, got dtype {raw_index.dtype}")
        point_index = _frozen_array(raw_index, np.int64, "point_index")
        normal_cam = _frozen_array(self.normal_cam, np.float64, "normal_cam")
        view_cam = _frozen_array(self.view_cam, np.float64, "view_cam")
        brightness = _frozen_array(self.brightness, np.float64, "brightness")

        if point_index.ndim != 1:
            raise ValueError(f"Observations.point_index must have shape (n_obs,), got {point_index.shape}")
        n_obs = point_index.shape[0]
        for name, array, shape in (
            ("normal_cam", normal_cam, (n_obs, 3)),
            ("view_cam", view_cam, (n_obs, 3)),
            ("brightness", brightness, (n_obs,)),
        ):
            if array.shape != shape:
                raise ValueError(f"Observations.{name} must have shape {shape} (n_obs={n_obs}), got {array.shape}")
            if not np.all(np.isfinite(array)):
                bad = int(np.count_nonzero(~np.isfinite(array)))
                raise ValueError(f"Observations.{name} has {bad} non-finite value(s)")
        for name, array in (("normal_cam", normal_cam), ("view_cam", view_cam)):
            length_error = np.abs(np.linalg.norm(array, axis=1) - 1.0)
            if n_obs and length_error.max() > UNIT_TOLERANCE:
                row = int(np.argmax(length_error))
                raise ValueError(
                    f"Observations.{name} must hold unit vectors (tolerance {UNIT_TOLERANCE:g}); "
                    f"row {row} has length {np.linalg.norm(array[row]):.9g}"
                )
        if n_obs and (point_index.min() < 0 or point_index.max() >= self.n_points):
            raise ValueError(
                f"Observations.point_index must lie in [0, {self.n_points}), "
                f"got values in [{point_index.min()}, {point_index.max()}]"
            )
        cos_emission = np.einsum("ij,ij->i", normal_cam, view_cam)
        if n_obs and cos_emission.min() <= 0.0:
            row = int(np.argmin(cos_emission))
            raise ValueError(
                f"Observations: every row must see the front of its surface (cos_emission > 0); "
                f"row {row} has cos_emission {cos_emission[row]:.6g}"
            )
        cos_emission.flags.writeable = False

        object.__setattr__(self, "point_index", point_index)
        object.__setattr__(self, "normal_cam", normal_cam)
        object.__setattr__(self, "view_cam", view_cam)
        object.__setattr__(self, "brightness", brightness)
        # A frozen dataclass has an instance __dict__; cache the derived column there.
        self.__dict__["cos_emission"] = cos_emission

    @functools.cached_property
    def cos_emission(self) -> np.ndarray:
        """``n . v`` per observation, the cosine of the emission angle (read-only)."""
        return np.einsum("ij,ij->i", self.normal_cam, self.view_cam)  # pragma: no cover - set in __post_init__

    @property
    def n_obs(self) -> int:
        return int(self.point_index.shape[0])

    @functools.cached_property
    def observations_per_point(self) -> np.ndarray:
        """Number of observations of each point, int64 (n_points,)."""
        return np.bincount(self.point_index, minlength=self.n_points)

    def cos_incidence(self, light_dir_cam) -> np.ndarray:
        """``n . l`` per observation for a camera-frame light direction (unclamped)."""
        return self.normal_cam @ np.asarray(light_dir_cam, dtype=np.float64)


@dataclasses.dataclass(frozen=True, eq=False)
class FitResult:
    """What an estimator returns. Arrays are per point; NaN where a point was not fitted."""

    method: str
    light_dir_cam: np.ndarray
    albedo: np.ndarray
    minnaert_k: np.ndarray
    n_points_fitted: int
    n_obs: int
    cost: float  # 0.5 * sum of squared brightness residuals at the estimate
    n_iterations: int
    nfev: int
    success: bool
    message: str
    fit_seconds: float
    solver: str = ""

    @property
    def light_angle_deg(self) -> float:
        return float(light_angle_deg(self.light_dir_cam))


# --------------------------------------------------------------------------
# Geometry helpers
# --------------------------------------------------------------------------


def light_from_tangent(a_b) -> np.ndarray:
    """Unit light direction ``normalize((a, b, -1))`` from gnomonic coordinates about -z.

    Accepts shape (2,) or (..., 2), returns (3,) or (..., 3). ``(0, 0)`` is the
    light straight from the camera (light angle 0); ``hypot(a, b)`` is the
    tangent of the light angle.
    """
    a_b = np.asarray(a_b, dtype=np.float64)
    if a_b.shape[-1] != 2:
        raise ValueError(f"light_from_tangent expects (..., 2) tangent coordinates, got shape {a_b.shape}")
    direction = np.concatenate([a_b, -np.ones(a_b.shape[:-1] + (1,))], axis=-1)
    return direction / np.linalg.norm(direction, axis=-1, keepdims=True)


def tangent_from_light(light_dir_cam) -> np.ndarray:
    """Gnomonic coordinates ``(a, b) = (l_x, l_y) / (-l_z)`` of a light direction.

    The chart covers the hemisphere towards the camera only, so ``l_z < 0`` is
    required (a ``ValueError`` otherwise). ``l`` need not be normalised.
    """
    light = np.asarray(light_dir_cam, dtype=np.float64)
    if light.shape[-1] != 3:
        raise ValueError(f"tangent_from_light expects (..., 3) directions, got shape {light.shape}")
    if not np.all(np.isfinite(light)):
        raise ValueError("tangent_from_light: light direction is not finite")
    if np.any(light[..., 2] >= 0.0):
        raise ValueError(
            "tangent_from_light: the light must come from the camera's hemisphere (l_z < 0, light angle "
            f"< 90 deg); got l_z = {np.max(light[..., 2]):.6g}. The tangent chart about -z cannot represent it."
        )
    return light[..., :2] / (-light[..., 2:3])


def angle_between_deg(direction_1, direction_2) -> np.ndarray | float:
    """Angle in degrees between two directions (any length), stable near 0 and 180.

    Uses ``atan2(|d1 x d2|, d1 . d2)``, which keeps full precision for tiny
    angles where ``arccos`` of the dot product loses it. Broadcasts over
    leading axes.
    """
    d1 = np.asarray(direction_1, dtype=np.float64)
    d2 = np.asarray(direction_2, dtype=np.float64)
    cross = np.linalg.norm(np.cross(d1, d2), axis=-1)
    dot = np.sum(d1 * d2, axis=-1)
    angle = np.degrees(np.arctan2(cross, dot))
    return float(angle) if np.ndim(angle) == 0 else angle


def light_angle_deg(light_dir_cam) -> np.ndarray | float:
    """Light angle in degrees: between the light direction and -z (towards the camera)."""
    return angle_between_deg(light_dir_cam, np.array([0.0, 0.0, -1.0]))


def minnaert_brightness(albedo, minnaert_k, cos_incidence, cos_emission) -> np.ndarray:
    """``albedo * cos_i**k * cos_o**(k - 1)``, zero where ``cos_i <= 0`` (unlit)."""
    cos_i = np.asarray(cos_incidence, dtype=np.float64)
    lit = cos_i > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        value = albedo * np.power(np.where(lit, cos_i, 1.0), minnaert_k) * np.power(cos_emission, minnaert_k - 1.0)
    return np.where(lit, value, 0.0)


def _point_layout(obs: Observations, min_observations: int):
    """Which points are fitted, and each row's column index among the fitted points."""
    counts = obs.observations_per_point
    fitted = counts >= max(min_observations, 1)
    local_of_point = np.cumsum(fitted) - 1
    row_used = fitted[obs.point_index]
    return fitted, local_of_point, row_used


# --------------------------------------------------------------------------
# Iwano's baseline
# --------------------------------------------------------------------------


def fit_iwano_linear(obs: Observations, minnaert_k: float) -> FitResult:
    """Iwano's estimator: one global albedo, known Minnaert k, linear least squares.

    With ``s = albedo**(1/k) * l`` the Minnaert law reads
    ``(b / cos_o**(k-1))**(1/k) = n . s``, so ``s`` solves
    ``min_s sum_j (n_j . s - (b_j / cos_o_j**(k-1))**(1/k))**2`` and
    ``l = s / |s|``, ``albedo = |s|**k``. Non-positive brightness (noise)
    goes through a signed power so that it stays unbiased in sign.

    Every point with at least one observation gets the same albedo and
    ``minnaert_k``; points without observations get NaN. ``cost`` is
    ``0.5 * sum (b - model)**2`` in brightness units, comparable with the LM fit.
    """
    start = time.perf_counter()
    minnaert_k = float(minnaert_k)
    if not np.isfinite(minnaert_k) or minnaert_k <= 0.0:
        raise ValueError(f"fit_iwano_linear: minnaert_k must be a positive number, got {minnaert_k}")
    if obs.n_obs < 3:
        raise ValueError(f"fit_iwano_linear needs at least 3 observations, got {obs.n_obs}")

    cos_o = obs.cos_emission
    reduced = obs.brightness / cos_o ** (minnaert_k - 1.0)
    target = np.sign(reduced) * np.abs(reduced) ** (1.0 / minnaert_k)
    s, _, rank, _ = np.linalg.lstsq(obs.normal_cam, target, rcond=None)
    s_norm = float(np.linalg.norm(s))
    if rank < 3 or s_norm == 0.0:
        raise ValueError(f"fit_iwano_linear: the normals do not span 3-D (rank {rank}) or s = 0")
    light = s / s_norm
    albedo = s_norm**minnaert_k

    model = minnaert_brightness(albedo, minnaert_k, obs.normal_cam @ light, cos_o)
    cost = 0.5 * float(np.sum((obs.brightness - model) ** 2))
    observed = obs.observations_per_point > 0
    elapsed = time.perf_counter() - start
    return FitResult(
        method="iwano_linear",
        light_dir_cam=light,
        albedo=np.where(observed, albedo, np.nan),
        minnaert_k=np.where(observed, minnaert_k, np.nan),
        n_points_fitted=int(np.count_nonzero(observed)),
        n_obs=obs.n_obs,
        cost=cost,
        n_iterations=1,
        nfev=1,
        success=True,
        message="linear least squares (numpy.linalg.lstsq)",
        fit_seconds=elapsed,
        solver="numpy.linalg.lstsq",
    )


# --------------------------------------------------------------------------
# Koizumi et al.: joint non-linear fit
# --------------------------------------------------------------------------


class KoizumiProblem:
    """Residuals and Jacobian of the joint fit, for the fitted points of ``obs``.

    Parameter vector ``x = [a, b, albedo_0 .. albedo_{m-1}, k_0 .. k_{m-1}]``
    with ``(a, b)`` the light's tangent coordinates (:func:`light_from_tangent`)
    and ``m`` the number of fitted points (those with at least
    ``min_observations`` rows), in increasing point order. Residuals are
    ``model - b`` for the rows of fitted points.
    """

    def __init__(self, obs: Observations, min_observations: int = 2, cos_floor: float = COS_INCIDENCE_FLOOR):
        self.obs = obs
        self.cos_floor = float(cos_floor)
        self.fitted, local_of_point, row_used = _point_layout(obs, min_observations)
        self.n_fitted = int(np.count_nonzero(self.fitted))
        self.n_params = 2 + 2 * self.n_fitted
        self.row_used = row_used
        self.all_rows = bool(np.all(row_used))
        take = (lambda a: a) if self.all_rows else (lambda a: a[row_used])
        self.local = take(local_of_point[obs.point_index])
        self.normal = np.ascontiguousarray(take(obs.normal_cam))
        self.brightness = take(obs.brightness)
        self.log_cos_o = np.log(take(obs.cos_emission))
        self.n_rows = int(self.local.shape[0])
        # CSR layout of the Jacobian: 4 entries per row, columns already sorted.
        self._indptr = np.arange(0, 4 * self.n_rows + 1, 4, dtype=np.int64)
        self._indices = np.column_stack(
            [
                np.zeros(self.n_rows, np.int64),
                np.ones(self.n_rows, np.int64),
                2 + self.local,
                2 + self.n_fitted + self.local,
            ]
        ).ravel()

    # -- packing --------------------------------------------------------
    def pack(self, tangent, albedo_fitted, k_fitted) -> np.ndarray:
        return np.concatenate([np.asarray(tangent, float), np.asarray(albedo_fitted, float), np.asarray(k_fitted, float)])

    def unpack(self, x):
        m = self.n_fitted
        return x[:2], x[2 : 2 + m], x[2 + m :]

    # -- model ----------------------------------------------------------
    def _evaluate(self, x, with_jacobian):
        tangent, albedo, k = self.unpack(x)
        u_norm = np.sqrt(1.0 + tangent[0] ** 2 + tangent[1] ** 2)
        light = np.array([tangent[0], tangent[1], -1.0]) / u_norm
        cos_i_raw = self.normal @ light
        cos_i = np.maximum(cos_i_raw, self.cos_floor)
        log_cos_i = np.log(cos_i)
        k_row = k[self.local]
        with np.errstate(over="ignore"):  # a wild trial k may overflow: infinite cost, step rejected
            shape_term = np.exp(k_row * log_cos_i + (k_row - 1.0) * self.log_cos_o)  # cos_i^k cos_o^(k-1)
        model = albedo[self.local] * shape_term
        residual = model - self.brightness
        if not with_jacobian:
            return residual, None
        d_albedo = shape_term
        d_k = model * (log_cos_i + self.log_cos_o)
        # d model / d l = albedo k cos_i^(k-1) cos_o^(k-1) n; zero where the floor is active.
        d_light_scale = np.where(cos_i_raw > self.cos_floor, model * k_row / cos_i, 0.0)
        # d l / d a = (e_x - l l_x) / |u|, d l / d b = (e_y - l l_y) / |u|.
        dl_da = (np.array([1.0, 0.0, 0.0]) - light * light[0]) / u_norm
        dl_db = (np.array([0.0, 1.0, 0.0]) - light * light[1]) / u_norm
        d_a = d_light_scale * (self.normal @ dl_da)
        d_b = d_light_scale * (self.normal @ dl_db)
        return residual, (d_a, d_b, d_albedo, d_k)

    def residuals(self, x) -> np.ndarray:
        return self._evaluate(x, False)[0]

    def jacobian_columns(self, x):
        """The 4 non-zeros of each Jacobian row: d/da, d/db, d/d albedo_p, d/d k_p."""
        return self._evaluate(x, True)[1]

    def jacobian(self, x) -> scipy.sparse.csr_matrix:
        """Sparse Jacobian (n_rows, n_params) in CSR, built without loops."""
        data = np.column_stack(self.jacobian_columns(x)).ravel()
        return scipy.sparse.csr_matrix(
            (data, self._indices, self._indptr), shape=(self.n_rows, self.n_params), copy=False
        )

    def cost(self, x) -> float:
        residual = self.residuals(x)
        return 0.5 * float(residual @ residual)

    # -- result ---------------------------------------------------------
    def per_point(self, values_fitted) -> np.ndarray:
        out = np.full(self.obs.n_points, np.nan)
        out[self.fitted] = values_fitted
        return out


def initial_albedo_and_k(problem: KoizumiProblem, light_dir_cam):
    """Closed-form per-point albedo and k for a given light, all points at once.

    Taking logs of the Minnaert law gives a line per point,
    ``log b + log cos_o = log albedo + k (log cos_i + log cos_o)``; it is
    fitted by weighted least squares with weights ``b**2`` (so that the log
    residuals approximate brightness residuals), through 2x2 normal
    equations accumulated with ``np.bincount``. k is clipped to
    ``INIT_K_RANGE`` and the albedo refitted for the clipped k. Points whose
    system is singular (no spread in ``log cos_i + log cos_o``, or no
    positive brightness) get k = 1 and the mean albedo of the others.
    Observations with ``b <= 0`` or ``cos_i <= 0`` get zero weight.
    """
    light = np.asarray(light_dir_cam, dtype=np.float64)
    cos_i = problem.normal @ light
    usable = (problem.brightness > 0.0) & (cos_i > 0.0)
    weight = np.where(usable, problem.brightness**2, 0.0)
    log_cos_i = np.log(np.where(usable, cos_i, 1.0))
    log_b = np.log(np.where(usable, problem.brightness, 1.0))
    x = log_cos_i + problem.log_cos_o
    y = log_b + problem.log_cos_o

    m = problem.n_fitted
    sums = [np.bincount(problem.local, weights=w, minlength=m) for w in (weight, weight * x, weight * y)]
    s0, sx, sy = sums
    # Centre per point before forming second moments: avoids cancellation.
    with np.errstate(invalid="ignore", divide="ignore"):
        x_mean = np.where(s0 > 0, sx / s0, 0.0)
        y_mean = np.where(s0 > 0, sy / s0, 0.0)
    dx = x - x_mean[problem.local]
    dy = y - y_mean[problem.local]
    sxx = np.bincount(problem.local, weights=weight * dx * dx, minlength=m)
    sxy = np.bincount(problem.local, weights=weight * dx * dy, minlength=m)
    # Weighted variance of x per point; below this the slope is undetermined.
    with np.errstate(invalid="ignore", divide="ignore"):
        variance = np.where(s0 > 0, sxx / s0, 0.0)
        regular = (s0 > 0) & (variance > 1e-12)
        k = np.where(regular, sxy / np.where(regular, sxx, 1.0), 1.0)
    k = np.clip(k, *INIT_K_RANGE)
    log_albedo = y_mean - k * x_mean
    albedo = np.exp(log_albedo)
    fallback = float(np.mean(albedo[regular])) if np.any(regular) else 1.0
    albedo = np.where(regular, albedo, fallback)
    k = np.where(regular, k, 1.0)
    return albedo, k


def profile_cost(problem: KoizumiProblem, light_dir_cam) -> float:
    """Cost of a light direction with every point's albedo and k from :func:`initial_albedo_and_k`.

    A cheap stand-in for the joint cost minimised over the per-point
    parameters: one pass of closed-form fits, no iterations.
    """
    albedo, k = initial_albedo_and_k(problem, light_dir_cam)
    return problem.cost(problem.pack(tangent_from_light(light_dir_cam), albedo, k))


def search_light(
    problem: KoizumiProblem,
    light_guess,
    *,
    max_points: int = 500,
    half_width: float = 0.8,
    n_grid: int = 17,
    n_refine: int = 2,
) -> np.ndarray:
    """Coarse-to-fine grid search of the light by :func:`profile_cost`, for LM's start.

    Why: when the albedo varies from point to point, Iwano's single-albedo
    guess can be many degrees off along the spin axis (17 deg for albedo
    uniform in [0.3, 0.8] at a 10 deg light angle), where the joint cost has
    a long, shallow valley; with few views per point and noise LM then stops
    in a local minimum. The profile cost is cheap and its minimum over a
    grid lands in the right basin.

    The grid covers tangent coordinates ``[-half_width, half_width]**2``
    (light angles up to about 39 deg along the axes at 0.8) with ``n_grid**2``
    nodes, plus ``light_guess``; each of ``n_refine`` levels then searches a
    7x7 grid over +-1 cell around the best node with a 3x finer step. Only
    ``max_points`` points (evenly spaced in index order) enter the search.
    """
    obs = problem.obs
    fitted_points = np.flatnonzero(problem.fitted)
    if fitted_points.size > max_points:
        chosen = np.zeros(obs.n_points, bool)
        chosen[fitted_points[np.linspace(0, fitted_points.size - 1, max_points).astype(np.int64)]] = True
        rows = chosen[obs.point_index]
        obs = Observations(
            obs.point_index[rows], obs.normal_cam[rows], obs.view_cam[rows], obs.brightness[rows], obs.n_points
        )
        problem = KoizumiProblem(obs, min_observations=1, cos_floor=problem.cos_floor)

    best_tangent = tangent_from_light(light_guess)
    best_cost = profile_cost(problem, light_from_tangent(best_tangent))
    centre, step = np.zeros(2), 2.0 * half_width / (n_grid - 1)
    offsets = np.linspace(-half_width, half_width, n_grid)
    for level in range(n_refine + 1):
        for da in offsets:
            for db in offsets:  # a few hundred cheap evaluations, not a loop over points
                tangent = centre + (da, db)
                cost = profile_cost(problem, light_from_tangent(tangent))
                if cost < best_cost:
                    best_cost, best_tangent = cost, tangent
        centre = best_tangent
        offsets = np.linspace(-step, step, 7)
        step = step / 3.0
    return light_from_tangent(best_tangent)


def _initial_parameters(problem: KoizumiProblem, light_init):
    obs = problem.obs
    if light_init is None or (isinstance(light_init, str) and light_init == "iwano"):
        # Lambert guess (k = 1, one albedo) for the light: linear and cheap.
        guess = fit_iwano_linear(obs, 1.0).light_dir_cam
        light_init = search_light(problem, guess) if light_init is None else guess
    elif isinstance(light_init, str):
        raise ValueError(f"light_init must be None, 'iwano' or a (3,) vector, got {light_init!r}")
    light_init = np.asarray(light_init, dtype=np.float64)
    if light_init.shape != (3,) or not np.all(np.isfinite(light_init)):
        raise ValueError(f"light_init must be a finite (3,) vector, got {light_init!r}")
    light_init = light_init / np.linalg.norm(light_init)
    tangent = tangent_from_light(light_init)
    albedo, k = initial_albedo_and_k(problem, light_init)
    return problem.pack(tangent, albedo, k)


def _solve_least_squares(problem: KoizumiProblem, x0, ftol, xtol, gtol, max_nfev, verbose, lsmr_tol):
    """The generic path: scipy's trust-region reflective with a sparse Jacobian and LSMR."""
    result = scipy.optimize.least_squares(
        problem.residuals,
        x0,
        jac=problem.jacobian,
        method="trf",
        tr_solver="lsmr",
        tr_options={"atol": lsmr_tol, "btol": lsmr_tol},
        x_scale="jac",
        ftol=ftol,
        xtol=xtol,
        gtol=gtol,
        max_nfev=max_nfev,
        verbose=verbose,
    )
    return result.x, float(result.cost), int(result.njev or 0), int(result.nfev), bool(result.success), str(result.message)


def _solve_block_lm(problem: KoizumiProblem, x0, ftol, xtol, gtol, max_nfev, verbose, hold_light=False):
    """Levenberg-Marquardt exploiting the arrow structure of J^T J.

    Each residual depends on the two light parameters and on its own point's
    (albedo, k). The damped normal matrix is therefore a 2x2 light block V,
    2x2 point blocks U_p and 2x2 couplings W_p; eliminating the point blocks
    (Schur complement) leaves a 2x2 system for the light step, after which
    each point's step follows in closed form. One iteration costs a few
    passes over the observations; a damped re-solve after a rejected step
    costs O(n_points) plus one residual evaluation.

    Damping is Marquardt's ``lambda * D`` with D the running maximum of
    diag(J^T J) (MINPACK's scaling, like ``x_scale="jac"``); lambda follows
    Nielsen's gain-ratio rule. Stopping mirrors least_squares: ftol on the
    relative cost decrease, xtol on the step relative to ``|x|``, gtol on the
    scaled gradient, or ``max_nfev`` residual evaluations.

    ``hold_light``: the light stays at ``x0``'s; the couplings and the light's
    gradient are zeroed, so its step is exactly zero and each point's step is
    its own 2x2 solve.
    """
    local = problem.local
    m = problem.n_fitted
    x = x0.copy()
    tiny = np.finfo(float).tiny

    def bsum(weights):
        return np.bincount(local, weights=weights, minlength=m)

    residual, columns = problem._evaluate(x, True)
    cost = 0.5 * float(residual @ residual)
    nfev, n_iterations = 1, 0
    damping, nu = 1e-3, 2.0
    scale_light = np.full(2, tiny)
    scale_point = np.full((2, m), tiny)
    status = None  # (success, message) once stopped

    while status is None:
        d_a, d_b, d_rho, d_k = columns
        # Blocks of J^T J and J^T r.
        v_aa, v_ab, v_bb = float(d_a @ d_a), float(d_a @ d_b), float(d_b @ d_b)
        u_rr, u_rk, u_kk = bsum(d_rho * d_rho), bsum(d_rho * d_k), bsum(d_k * d_k)
        w_ar, w_ak, w_br, w_bk = bsum(d_a * d_rho), bsum(d_a * d_k), bsum(d_b * d_rho), bsum(d_b * d_k)
        g_a, g_b = float(d_a @ residual), float(d_b @ residual)
        g_r, g_k = bsum(d_rho * residual), bsum(d_k * residual)
        if hold_light:
            w_ar = w_ak = w_br = w_bk = np.zeros(m)
            g_a = g_b = 0.0
        gradient = np.concatenate([[g_a, g_b], g_r, g_k])

        scale_light = np.maximum(scale_light, [v_aa, v_bb])
        scale_point = np.maximum(scale_point, np.stack([u_rr, u_kk]))
        scale = np.concatenate([scale_light, scale_point[0], scale_point[1]])
        if cost == 0.0 or np.max(np.abs(gradient) / np.sqrt(scale)) < gtol:
            status = True, "gtol: the scaled gradient is below tolerance"
            break

        while True:  # raise the damping until a step lowers the cost
            step_light, step_albedo, step_k = solve_arrow_system(
                (v_aa + damping * scale_light[0], v_ab, v_bb + damping * scale_light[1]),
                (u_rr + damping * scale_point[0], u_rk, u_kk + damping * scale_point[1]),
                (w_ar, w_ak, w_br, w_bk),
                (g_a, g_b),
                (g_r, g_k),
            )
            step = np.concatenate([step_light, step_albedo, step_k])
            if not np.all(np.isfinite(step)):
                status = False, "the damped normal equations became singular"
                break

            x_new = x + step
            residual_new = problem.residuals(x_new)
            nfev += 1
            cost_new = 0.5 * float(residual_new @ residual_new)
            predicted = 0.5 * float(step @ (damping * scale * step - gradient))
            actual = cost - cost_new
            step_small = np.linalg.norm(step) <= xtol * (xtol + np.linalg.norm(x))
            if actual > 0.0 and predicted > 0.0:
                gain = actual / predicted
                x, residual, cost = x_new, residual_new, cost_new
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                if actual < ftol * (cost + actual):
                    status = True, "ftol: the relative reduction of the cost is below tolerance"
                elif step_small:
                    status = True, "xtol: the step is below tolerance"
                break
            damping *= nu
            nu *= 2.0
            if damping > 1e30:
                status = True, "the cost cannot be lowered further (machine precision)"
                break
            if step_small:
                status = True, "xtol: the step is below tolerance (no further decrease)"
                break
            if nfev >= max_nfev:
                break
        n_iterations += 1
        if verbose:
            print(f"block LM iteration {n_iterations}: cost {cost:.6e}, damping {damping:.2e}, nfev {nfev}")
        if status is None and nfev >= max_nfev:
            status = False, f"maximum number of function evaluations ({max_nfev}) reached"
        if status is None:
            residual, columns = problem._evaluate(x, True)
    success, message = status
    return x, cost, n_iterations, nfev, success, message


# --------------------------------------------------------------------------
# Arrow-structured normal equations (shared with varpro and fisher)
# --------------------------------------------------------------------------
#
# Every residual depends on the light's two tangent coordinates (a, b) and on
# its own point's two parameters (albedo or log albedo, and k). J^T W J is
# therefore an "arrow": a 2x2 light block V, a 2x2 block U_p per point and a
# 2x2 coupling W_p per point (rows a, b; columns the point's two parameters),
# zero elsewhere. Blocks are passed as tuples of their distinct entries so
# that per-point values are flat (m,) arrays: V = (v_aa, v_ab, v_bb),
# U = (u_11, u_12, u_22), W = (w_a1, w_a2, w_b1, w_b2).


def _schur_complement(light_block, point_blocks, couplings):
    """The pieces both arrow-system functions need (call inside ``np.errstate``).

    Returns each point's ``U_p^-1`` as ``(i11, i12, i22)``, ``Y_p = W_p U_p^-1``
    as ``(y_a1, y_a2, y_b1, y_b2)`` (rows: the light's a, b; columns: the
    point's two parameters) and the Schur complement ``S = V - sum_p Y_p
    W_p^T`` as ``(s_aa, s_ab, s_bb)``.
    """
    v_aa, v_ab, v_bb = light_block
    u_11, u_12, u_22 = point_blocks
    w_a1, w_a2, w_b1, w_b2 = couplings
    det = u_11 * u_22 - u_12 * u_12
    i11, i22, i12 = u_22 / det, u_11 / det, -u_12 / det
    y_a1 = w_a1 * i11 + w_a2 * i12
    y_a2 = w_a1 * i12 + w_a2 * i22
    y_b1 = w_b1 * i11 + w_b2 * i12
    y_b2 = w_b1 * i12 + w_b2 * i22
    s_aa = v_aa - float(np.sum(y_a1 * w_a1 + y_a2 * w_a2))
    s_ab = v_ab - float(np.sum(y_a1 * w_b1 + y_a2 * w_b2))
    s_bb = v_bb - float(np.sum(y_b1 * w_b1 + y_b2 * w_b2))
    return (i11, i12, i22), (y_a1, y_a2, y_b1, y_b2), (s_aa, s_ab, s_bb)


def solve_arrow_system(light_block, point_blocks, couplings, light_gradient, point_gradient):
    """Solve ``[[V, W], [W^T, U]] [d_light; d_point] = -[g_light; g_point]`` by the Schur complement.

    ``light_block`` = (v_aa, v_ab, v_bb) floats, ``point_blocks`` = (u_11,
    u_12, u_22) and ``couplings`` = (w_a1, w_a2, w_b1, w_b2) arrays (m,),
    ``light_gradient`` = (g_a, g_b), ``point_gradient`` = (g_1, g_2) arrays (m,).
    Damping, if any, is already added to the diagonals by the caller. The
    point blocks are eliminated (S = V - sum_p W_p U_p^-1 W_p^T), the 2x2
    light system solved, and each point's step back-substituted:
    ``U_p d_p = -g_p - W_p^T d_light``. O(m); returns ``(step_light (2,),
    step_1 (m,), step_2 (m,))``, non-finite where a block is singular.
    """
    w_a1, w_a2, w_b1, w_b2 = couplings
    g_a, g_b = light_gradient
    g_1, g_2 = point_gradient
    with np.errstate(divide="ignore", invalid="ignore"):
        (i11, i12, i22), (y_a1, y_a2, y_b1, y_b2), (s_aa, s_ab, s_bb) = _schur_complement(light_block, point_blocks, couplings)
        # The Schur complement's right-hand side.
        rhs_a = -g_a + float(np.sum(y_a1 * g_1 + y_a2 * g_2))
        rhs_b = -g_b + float(np.sum(y_b1 * g_1 + y_b2 * g_2))
        s_det = s_aa * s_bb - s_ab * s_ab
        step_a = (s_bb * rhs_a - s_ab * rhs_b) / s_det
        step_b = (s_aa * rhs_b - s_ab * rhs_a) / s_det
        # Back-substitute each point's step: U_p d_p = -g_p - W_p^T d_light.
        q_1 = -g_1 - w_a1 * step_a - w_b1 * step_b
        q_2 = -g_2 - w_a2 * step_a - w_b2 * step_b
        return np.array([step_a, step_b]), i11 * q_1 + i12 * q_2, i12 * q_1 + i22 * q_2


def arrow_covariance(light_block, point_blocks, couplings):
    """Inverse of an arrow-structured ``J^T W J``: the light block and each point's marginal 2x2 block.

    Same block arguments as :func:`solve_arrow_system` (undamped). With
    ``S = V - sum_p W_p U_p^-1 W_p^T`` the light covariance is ``S^-1`` and
    point p's marginal covariance ``U_p^-1 + Y_p^T S^-1 Y_p`` with ``Y_p =
    W_p U_p^-1``: its own uncertainty plus what the light's uncertainty
    passes on to it. With weights ``1/sigma_j**2`` in J^T W J this is the
    Gauss-Newton covariance of the weighted least-squares estimate (and, at
    the true parameters, the Cramer-Rao bound).

    Returns ``(light_cov (2, 2), var_1 (m,), var_2 (m,), cov_12 (m,))``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        (i11, i12, i22), (y_a1, y_a2, y_b1, y_b2), (s_aa, s_ab, s_bb) = _schur_complement(light_block, point_blocks, couplings)
        light_cov = np.linalg.inv(np.array([[s_aa, s_ab], [s_ab, s_bb]]))
        c_aa, c_ab, c_bb = light_cov[0, 0], light_cov[0, 1], light_cov[1, 1]
        var_1 = i11 + c_aa * y_a1 * y_a1 + 2.0 * c_ab * y_a1 * y_b1 + c_bb * y_b1 * y_b1
        var_2 = i22 + c_aa * y_a2 * y_a2 + 2.0 * c_ab * y_a2 * y_b2 + c_bb * y_b2 * y_b2
        cov_12 = i12 + c_aa * y_a1 * y_a2 + c_ab * (y_a1 * y_b2 + y_b1 * y_a2) + c_bb * y_b1 * y_b2
    return light_cov, var_1, var_2, cov_12


def light_std_deg(light_tangent, light_cov_tangent) -> float:
    """Angular standard deviation (degrees) of a light direction from its tangent-coordinate covariance.

    ``l = normalize((a, b, -1))``; with ``M = dl/d(a, b)`` (3x2) the
    direction's covariance is ``M C M^T``, and for small errors the expected
    squared angle between estimate and truth is its trace. Returns
    ``degrees(sqrt(trace(M^T M C)))``: the RMS angular error, summed over
    both directions across the line of sight of the light.
    """
    a, b = np.asarray(light_tangent, dtype=np.float64)
    norm = np.sqrt(1.0 + a * a + b * b)
    light = np.array([a, b, -1.0]) / norm
    jacobian = np.column_stack(
        [(np.array([1.0, 0.0, 0.0]) - light * light[0]) / norm, (np.array([0.0, 1.0, 0.0]) - light * light[1]) / norm]
    )
    variance = float(np.trace(jacobian.T @ jacobian @ np.asarray(light_cov_tangent, dtype=np.float64)))
    return float(np.degrees(np.sqrt(max(variance, 0.0))))


SOLVERS = ("block_lm", "least_squares")


def fit_koizumi_lm(
    obs: Observations,
    light_init=None,
    *,
    solver: str = "block_lm",
    ftol: float = 1e-14,
    xtol: float = 1e-14,
    gtol: float = 1e-14,
    max_nfev: int | None = None,
    min_observations: int = 2,
    lsmr_tol: float = 1e-10,
    verbose: int = 0,
    hold_light: bool = False,
) -> FitResult:
    """The paper's estimator: one global light, an albedo and a Minnaert k per point.

    Minimises ``sum_j (b_j - albedo_p cos_i_j**k_p cos_o_j**(k_p - 1))**2``
    over the light's tangent coordinates (:func:`light_from_tangent`) and every
    fitted point's albedo and k, jointly.

    Parameters
    ----------
    obs : Observations
        Observations must be lit at the truth (``cos_i > 0``; ``observe``
        keeps ``cos_i > min_cos_incidence``). Inside the residual ``cos_i`` is
        floored at ``COS_INCIDENCE_FLOOR`` so a trial step never breaks log/pow.
    light_init : None, "iwano" or (3,) array
        Starting light. ``None`` (default): Iwano's linear fit with k = 1 (a
        Lambert guess), then :func:`search_light`, a coarse-to-fine grid
        search of the profile cost that guards against Iwano's bias when the
        albedo varies. ``"iwano"``: the Lambert guess alone. A (3,) vector:
        that light (camera frame, ``l_z < 0``). Per-point albedo and k always
        start from the closed-form log-linear fit (:func:`initial_albedo_and_k`).
    solver : {"block_lm", "least_squares"}
        ``"block_lm"`` (default): Levenberg-Marquardt written here that
        solves each step exactly through the arrow structure of J^T J (per
        point 2x2 blocks, Schur complement on the 2x2 light block).
        ``"least_squares"``: ``scipy.optimize.least_squares(method="trf",
        tr_solver="lsmr", x_scale="jac")`` with the analytic sparse Jacobian;
        kept as an independent check. Measured on 50,000 points x 20
        observations, noiseless, 2 cores: block_lm 0.4-0.9 s, least_squares
        2-10 s, both recovering light, albedo and k to ~1e-15. With noise
        (sigma 0.005) the two agree to ~5e-9 and block_lm ends nearer the
        optimum (scaled gradient 1e-11 against 4e-9), LSMR being inexact.
    ftol, xtol, gtol, max_nfev
        Stopping rules with least_squares' meaning. ``max_nfev`` defaults to
        200 for block_lm and 100 * n_params capped at 2000 for least_squares.
    min_observations : int
        Points with fewer observations are not fitted (NaN): one observation
        cannot separate albedo from k.
    lsmr_tol : float
        ``atol``/``btol`` of LSMR in the least_squares path. scipy's default,
        1e-6, is enough on noiseless data but on noisy data its inexact steps
        make trf crawl (50,000 points, sigma 0.005: 845 evaluations, 320 s,
        light still 1.5e-5 deg off the optimum); 1e-10 converges in about 10.
    hold_light : bool
        Keep the light at ``light_init`` (a vector) and fit only each point's
        albedo and k under it (block_lm only): the second step of a two-step
        estimate whose light comes from elsewhere (:func:`fit_pooled_k`).
    """
    start = time.perf_counter()
    if hold_light and (solver != "block_lm" or light_init is None or isinstance(light_init, str)):
        raise ValueError("fit_koizumi_lm: hold_light needs solver='block_lm' and a (3,) light_init vector")
    if solver not in SOLVERS:
        raise ValueError(f"fit_koizumi_lm: solver must be one of {SOLVERS}, got {solver!r}")
    problem = KoizumiProblem(obs, min_observations=min_observations)
    if problem.n_fitted == 0 or problem.n_rows < problem.n_params:
        raise ValueError(
            f"fit_koizumi_lm: {problem.n_rows} usable observations of {problem.n_fitted} points "
            f"cannot determine {problem.n_params} unknowns"
        )
    x0 = _initial_parameters(problem, light_init)
    if solver == "block_lm":
        max_nfev = 200 if max_nfev is None else int(max_nfev)
        x, cost, n_iterations, nfev, success, message = _solve_block_lm(
            problem, x0, ftol, xtol, gtol, max_nfev, verbose, hold_light
        )
        solver_name = "block-Schur Levenberg-Marquardt (numpy)"
    else:
        max_nfev = min(100 * problem.n_params, 2000) if max_nfev is None else int(max_nfev)
        x, cost, n_iterations, nfev, success, message = _solve_least_squares(
            problem, x0, ftol, xtol, gtol, max_nfev, verbose, lsmr_tol
        )
        solver_name = "scipy.optimize.least_squares trf/lsmr, sparse analytic Jacobian"
    tangent, albedo, k = problem.unpack(x)
    elapsed = time.perf_counter() - start
    return FitResult(
        method="koizumi_lm",
        light_dir_cam=light_from_tangent(tangent),
        albedo=problem.per_point(albedo),
        minnaert_k=problem.per_point(k),
        n_points_fitted=problem.n_fitted,
        n_obs=problem.n_rows,
        cost=cost,
        n_iterations=n_iterations,
        nfev=nfev,
        success=success,
        message=message,
        fit_seconds=elapsed,
        solver=solver_name,
    )


def fit_pooled_k(obs: Observations, light_init, minnaert_k_init: float, *, min_observations: int = 2, ftol: float = 1e-12, xtol: float = 1e-12, max_nfev: int = 200) -> FitResult:
    """One light, an albedo per point and one Minnaert k for the whole body.

    The paper's model with k pooled over the points, as planetary photometry
    fits a Minnaert k to a region. It is the light step of the refinement
    (``refine``): with a free k per point the light's direction out of the
    plane of the views and the Sun is nearly a gauge freedom. A brightness
    offset ``c`` common to a point's views (what a tilt of the light out of
    that plane adds to ``cos_i`` at a point of latitude ``lat``: ``c = e
    tan(lat)``) changes ``log b`` by ``c / cos_i``, which is ``c`` (taken up
    by the albedo) plus ``-c log cos_i`` (taken up by a per-point k) to
    second order in the phase of the view. A per-point k therefore lets
    errors of 1e-3 in the samples move the light by a degree; one k for the
    body does not.

    Minimises ``sum_j (b_j - albedo_p cos_i_j**k cos_o_j**(k - 1))**2`` with
    ``scipy.optimize.least_squares`` (trf, analytic sparse Jacobian). Points
    with fewer than ``min_observations`` rows are left out (NaN).
    """
    start = time.perf_counter()
    problem = KoizumiProblem(obs, min_observations=min_observations)
    m = problem.n_fitted
    if m == 0 or problem.n_rows < m + 3:
        raise ValueError(f"fit_pooled_k: {problem.n_rows} usable observations of {m} points cannot determine {m + 3} unknowns")
    light_init = np.asarray(light_init, dtype=np.float64)
    if light_init.shape != (3,) or not np.all(np.isfinite(light_init)):
        raise ValueError(f"fit_pooled_k: light_init must be a finite (3,) vector, got {light_init!r}")
    if not np.isfinite(minnaert_k_init) or minnaert_k_init <= 0:
        raise ValueError(f"fit_pooled_k: minnaert_k_init must be a positive number, got {minnaert_k_init!r}")
    light_init = light_init / np.linalg.norm(light_init)
    # Start: each point's albedo by least squares under the initial light and k.
    shape_term = np.maximum(problem.normal @ light_init, problem.cos_floor) ** minnaert_k_init * np.exp((minnaert_k_init - 1.0) * problem.log_cos_o)
    albedo0 = np.bincount(problem.local, shape_term * problem.brightness, m) / np.bincount(problem.local, shape_term**2, m)
    x0 = np.concatenate([tangent_from_light(light_init), albedo0, [minnaert_k_init]])

    def expand(x):
        return problem.pack(x[:2], x[2:-1], np.full(m, x[-1]))

    # The problem's CSR layout, with every row's k entry in the one k column.
    indices = problem._indices.copy()
    indices[3::4] = 2 + m

    def jacobian(x):
        data = np.column_stack(problem.jacobian_columns(expand(x))).ravel()
        return scipy.sparse.csr_matrix((data, indices, problem._indptr), shape=(problem.n_rows, m + 3))

    solution = scipy.optimize.least_squares(
        lambda x: problem.residuals(expand(x)), x0, jac=jacobian, method="trf", x_scale="jac", ftol=ftol, xtol=xtol, gtol=1e-14, max_nfev=max_nfev,
    )
    tangent, albedo, k = problem.unpack(expand(solution.x))
    return FitResult(
        method="pooled_k",
        light_dir_cam=light_from_tangent(tangent),
        albedo=problem.per_point(albedo),
        minnaert_k=problem.per_point(k),
        n_points_fitted=m,
        n_obs=problem.n_rows,
        cost=float(solution.cost),
        n_iterations=int(solution.njev or 0),
        nfev=int(solution.nfev),
        success=bool(solution.success),
        message=str(solution.message),
        fit_seconds=time.perf_counter() - start,
        solver="scipy.optimize.least_squares trf, sparse analytic Jacobian, one k",
    )


# --------------------------------------------------------------------------
# Synthetic data
# --------------------------------------------------------------------------


def synthetic_observations(
    n_points: int,
    n_views: int,
    light_dir_cam,
    albedo,
    minnaert_k,
    rng: np.random.Generator,
    noise_sigma: float = 0.0,
    min_cos: float = 0.1,
    *,
    body_radius_m: float = 250.0,
    camera_distance_m: float = 5000.0,
    max_abs_spin_component: float = 0.85,
) -> Observations:
    """Observations of a turning body with a known truth (for tests and benchmarks).

    Geometry: the camera sits at the origin of the camera frame looking along
    +z; the body's centre is ``camera_distance_m`` down the axis and it spins
    about the camera's y axis (perpendicular to the optical axis), as in the
    paper's image sets. Point ``p`` has a random body-frame unit normal
    (uniform on the sphere within the band ``|n_y| <= max_abs_spin_component``,
    so that every point turns through a useful arc) and a body-frame position
    ``body_radius_m * u * n`` with ``u`` uniform in [0.6, 1]. The view vector
    is the true unit vector from the rotated point to the camera, so it
    departs from ``-z`` by up to ``atan(body_radius / distance)`` (about 3 deg
    by default): a realistic slight perspective.

    Each point is seen at ``n_views`` spin angles, stratified (one uniformly
    jittered angle per equal sub-interval) over the arc where it is both lit
    and visible, so ``cos_o`` and ``cos_i`` sweep from near ``min_cos`` to
    near their maximum and k is identifiable. Only rows with
    ``cos_i > min_cos`` and ``cos_o > min_cos`` are kept, so a point has at
    most ``n_views`` rows. ``albedo`` and ``minnaert_k`` are scalars or
    (n_points,) arrays. ``noise_sigma`` adds Gaussian noise (brightness
    units) to ``b``; noisy ``b`` may be slightly negative near the terminator.
    Deterministic given ``rng``.
    """
    n_points, n_views = int(n_points), int(n_views)
    if n_points < 0 or n_views < 1:
        raise ValueError(f"synthetic_observations: need n_points >= 0 and n_views >= 1, got {n_points}, {n_views}")
    light = np.asarray(light_dir_cam, dtype=np.float64)
    light = light / np.linalg.norm(light)
    albedo = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (n_points,))
    minnaert_k = np.broadcast_to(np.asarray(minnaert_k, dtype=np.float64), (n_points,))

    # Body-frame normals: uniform on the sphere restricted to a band about the spin equator.
    n_y = rng.uniform(-max_abs_spin_component, max_abs_spin_component, n_points)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n_points)
    ring = np.sqrt(1.0 - n_y**2)
    normal_body = np.column_stack([ring * np.cos(azimuth), n_y, ring * np.sin(azimuth)])
    position_body = body_radius_m * rng.uniform(0.6, 1.0, n_points)[:, None] * normal_body

    # After a spin by theta about y: n_z(theta) = -n_x sin(theta) + n_z cos(theta), so with the
    # camera towards -z, cos_o ~ r_o cos(theta - theta_o) and cos_i = r_i cos(theta - theta_i) + c_i.
    n_x, n_z = normal_body[:, 0], normal_body[:, 2]
    r_o = np.hypot(n_x, n_z)
    theta_o = np.arctan2(n_x, -n_z)
    coef_cos = n_x * light[0] + n_z * light[2]
    coef_sin = n_z * light[0] - n_x * light[2]
    r_i = np.hypot(coef_cos, coef_sin)
    theta_i = np.arctan2(coef_sin, coef_cos)
    c_i = n_y * light[1]
    with np.errstate(invalid="ignore", divide="ignore"):
        half_o = np.arccos(np.clip(min_cos / r_o, -1.0, 1.0))
        half_i = np.arccos(np.clip((min_cos - c_i) / np.where(r_i > 0, r_i, np.inf), -1.0, 1.0))
    offset = np.angle(np.exp(1j * (theta_i - theta_o)))  # lit arc centre relative to visible arc centre
    # Leave a margin for the perspective, which shifts cos_o a little from the -z approximation.
    margin = np.radians(4.0)
    low = np.maximum(-half_o, offset - half_i) + margin
    high = np.minimum(half_o, offset + half_i) - margin
    usable = high > low

    strata = (np.arange(n_views)[None, :] + rng.uniform(0.0, 1.0, (n_points, n_views))) / n_views
    theta = theta_o[:, None] + low[:, None] + (high - low)[:, None] * strata
    point_index = np.repeat(np.arange(n_points, dtype=np.int64), n_views)
    keep_point = np.repeat(usable, n_views)
    theta = theta.ravel()[keep_point]
    point_index = point_index[keep_point]

    # Rotate by theta about y: (x, y, z) -> (c x + s z, y, c z - s x), without per-row matrices.
    cos_theta, sin_theta = np.cos(theta), np.sin(theta)

    def rotated(vectors_body):
        vectors = vectors_body[point_index]
        out = np.empty_like(vectors)
        out[:, 0] = cos_theta * vectors[:, 0] + sin_theta * vectors[:, 2]
        out[:, 1] = vectors[:, 1]
        out[:, 2] = cos_theta * vectors[:, 2] - sin_theta * vectors[:, 0]
        return out

    normal_cam = rotated(normal_body)
    position_cam = rotated(position_body)
    del cos_theta, sin_theta
    position_cam[:, 2] += camera_distance_m
    view_cam = -position_cam / np.linalg.norm(position_cam, axis=1, keepdims=True)
    normal_cam /= np.linalg.norm(normal_cam, axis=1, keepdims=True)

    cos_i = normal_cam @ light
    cos_o = np.einsum("ij,ij->i", normal_cam, view_cam)
    keep = (cos_i > min_cos) & (cos_o > min_cos)
    point_index, normal_cam, view_cam = point_index[keep], normal_cam[keep], view_cam[keep]
    cos_i, cos_o = cos_i[keep], cos_o[keep]
    k_row = minnaert_k[point_index]
    brightness = albedo[point_index] * cos_i**k_row * cos_o ** (k_row - 1.0)
    if noise_sigma > 0.0:
        brightness = brightness + rng.normal(0.0, noise_sigma, brightness.shape)
    return Observations(
        point_index=point_index,
        normal_cam=normal_cam,
        view_cam=view_cam,
        brightness=brightness,
        n_points=n_points,
    )
