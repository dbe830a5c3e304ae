"""The data of every estimator: observations, results, the light's parametrisation.

For every surface point and every image that sees it, an observation holds
the point's unit normal and the unit vector towards the camera (both in that
image's camera frame) and the brightness sampled there. The estimators in
this package turn observations into a :class:`FitResult`.

The light is parameterised by gnomonic (tangent-plane) coordinates about the
direction towards the camera, ``-z``: ``l = normalize((a, b, -1))``. The light
in this problem is always close to ``-z`` (the paper's sets have light angles
of 0 and 10 degrees), and unlike spherical angles this chart is smooth and
well-conditioned at a light angle of exactly 0.

Frames and units follow the package conventions (``asteroid_photometry``):
camera frame with +z along the optical axis, ``light_dir_cam`` the unit
vector towards the Sun, angles in radians unless a name ends in ``_deg``.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

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

    def point_means(self, values) -> np.ndarray:
        """The mean over each point's rows of ``values`` (one per row, or one row of columns per row): (n_points,) or
        (n_points, columns); 0 for a point without rows."""
        values = np.asarray(values, dtype=np.float64)
        columns = values.reshape(self.n_obs, -1)
        sums = np.column_stack([np.bincount(self.point_index, weights=column, minlength=self.n_points) for column in columns.T])
        means = sums / np.maximum(self.observations_per_point, 1)[:, None]
        return means.reshape((self.n_points,) + values.shape[1:])

    def cos_incidence(self, light_dir_cam) -> np.ndarray:
        """``n . l`` per observation for a camera-frame light direction (unclamped)."""
        return self.normal_cam @ np.asarray(light_dir_cam, dtype=np.float64)

    def rows(self, keep) -> "Observations":
        """The observations of the rows ``keep`` (a mask or indices), the points' numbering kept."""
        return Observations(
            point_index=self.point_index[keep], normal_cam=self.normal_cam[keep], view_cam=self.view_cam[keep],
            brightness=self.brightness[keep], n_points=self.n_points,
        )


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


def _point_layout(obs: Observations, min_observations: int):
    """Which points are fitted, and each row's column index among the fitted points."""
    counts = obs.observations_per_point
    fitted = counts >= max(min_observations, 1)
    local_of_point = np.cumsum(fitted) - 1
    row_used = fitted[obs.point_index]
    return fitted, local_of_point, row_used


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
