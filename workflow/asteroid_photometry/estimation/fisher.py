"""Fisher information and Cramer-Rao bounds of the Minnaert observation model.

How well *can* the light direction, the albedo and the Minnaert k be
estimated from a given set of observations? Under the Gaussian model

    b_j ~ N(f_j(theta), variance_j),   f_j = albedo_p cos_i**k_p cos_o**(k_p - 1),

with ``theta`` the light's tangent coordinates (``core.light_from_tangent``)
and every point's (albedo, k), the Fisher information is ``J^T W J`` with
``J = df/dtheta`` at the true parameters and ``W = diag(1 / variance_j)``.
Its inverse bounds the covariance of any unbiased estimator (Cramer-Rao). The
matrix is an arrow (a 2x2 light block, a 2x2 block per point and their
couplings), so it is assembled in one streamed pass (``blocks``, the one the
``varpro`` estimator uses for its Gauss-Newton steps) and inverted through
the Schur complement (``arrow.arrow_covariance``): the light's 2x2
covariance bound and every point's marginal 2x2 bound, without ever forming
the (2 + 2 n_points)^2 matrix.

``variance`` is taken as known (not a function of theta): the bound of
weighted least squares. With shot noise the variance grows with the mean;
the information that carries is ``1 / (2 f gain)`` of the above per
observation (``noise`` module: under 1e-4 for its sensors), negligible.

Where it sits: after ``fit``, to say how far an estimator is from the best
possible on the same observations (:func:`efficiency`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import numpy as np

from asteroid_photometry.estimation.arrow import arrow_covariance
from asteroid_photometry.estimation.core import angle_between_deg, light_std_deg, Observations, tangent_from_light
from asteroid_photometry.estimation.blocks import brightness_normal_equations, PointBlocks
from asteroid_photometry.reflectance.laws import minnaert_brightness

__all__ = ["FisherBlocks", "fisher_blocks", "cramer_rao_bounds", "efficiency"]


@dataclasses.dataclass(frozen=True, eq=False)
class FisherBlocks:
    """The Fisher information ``J^T W J`` of the Minnaert model, by blocks.

    Parameters: the light's tangent coordinates ``(a, b)`` and, per point,
    ``(albedo, k)``. ``light`` (2, 2): the light block; ``point`` (n_points,
    2, 2): each point's own block; ``coupling`` (n_points, 2, 2): rows
    ``(a, b)``, columns ``(albedo, k)``. Points not included (fewer than
    ``min_observations`` observations) have NaN blocks and ``included``
    False. ``light_tangent``: where the information was evaluated.
    """

    light: np.ndarray
    point: np.ndarray
    coupling: np.ndarray
    included: np.ndarray
    light_tangent: np.ndarray
    n_obs: int

    def _arrow(self):
        rows = self.included
        point, coupling = self.point[rows], self.coupling[rows]
        light_block = (self.light[0, 0], self.light[0, 1], self.light[1, 1])
        point_blocks = (point[:, 0, 0], point[:, 0, 1], point[:, 1, 1])
        couplings = (coupling[:, 0, 0], coupling[:, 0, 1], coupling[:, 1, 0], coupling[:, 1, 1])
        return light_block, point_blocks, couplings

    def dense(self) -> np.ndarray:
        """The full matrix, order ``[a, b, albedo_0, k_0, albedo_1, k_1, ...]`` over included points (small problems)."""
        m = int(np.count_nonzero(self.included))
        matrix = np.zeros((2 + 2 * m, 2 + 2 * m))
        matrix[:2, :2] = self.light
        for slot, (point, coupling) in enumerate(zip(self.point[self.included], self.coupling[self.included])):
            block = slice(2 + 2 * slot, 4 + 2 * slot)
            matrix[block, block] = point
            matrix[:2, block] = coupling
            matrix[block, :2] = coupling.T
        return matrix


def _as_observations(observations) -> Observations:
    """An Observations, or one built from a geometry (point_index, normal_cam, view_cam, n_points)."""
    if isinstance(observations, Observations):
        return observations

    def field(name):
        if isinstance(observations, Mapping):
            return observations[name]
        return getattr(observations, name)

    try:
        point_index = field("point_index")
        return Observations(
            point_index=point_index,
            normal_cam=field("normal_cam"),
            view_cam=field("view_cam"),
            brightness=np.zeros(np.shape(point_index)),
            n_points=int(field("n_points")),
        )
    except (KeyError, AttributeError) as error:
        raise ValueError(
            "fisher: expected Observations or a geometry with point_index, normal_cam, view_cam and n_points; "
            f"missing {error}"
        ) from None


def _per_point(values, n_points, name):
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 0:
        return np.full(n_points, float(values))
    if values.shape != (n_points,):
        raise ValueError(f"fisher: {name} must be a scalar or have shape ({n_points},), got {values.shape}")
    return values


def fisher_blocks(
    observations,
    light_dir_cam,
    albedo,
    minnaert_k,
    variance,
    *,
    min_observations: int = 2,
) -> FisherBlocks:
    """Fisher information of the Gaussian Minnaert model at the given (true) parameters, by blocks.

    Parameters
    ----------
    observations : Observations, or a geometry
        Which point each observation sees and its camera-frame normal and
        view vector: an :class:`~.core.Observations` (its brightness is
        not used) or any mapping or object with ``point_index``,
        ``normal_cam``, ``view_cam`` and ``n_points``.
    light_dir_cam : (3,) array
        The light direction (camera frame, ``l_z < 0``).
    albedo, minnaert_k : float or (n_points,) arrays
        Per-point parameters.
    variance : float, (n_obs,) array or callable
        The observations' noise variance (brightness units squared). A
        callable gets the true brightness ``f_j`` (n_obs,) and returns the
        variances, e.g. ``lambda b: noise.observation_variance(b, sensor)``.
    min_observations : int
        Points with fewer observations are left out (their blocks are NaN):
        one observation cannot separate albedo from k.
    """
    obs = _as_observations(observations)
    light = np.asarray(light_dir_cam, dtype=np.float64)
    light = light / np.linalg.norm(light)
    tangent = tangent_from_light(light)
    albedo = _per_point(albedo, obs.n_points, "albedo")
    minnaert_k = _per_point(minnaert_k, obs.n_points, "minnaert_k")
    if callable(variance):
        truth = minnaert_brightness(albedo[obs.point_index], minnaert_k[obs.point_index], obs.cos_incidence(light), obs.cos_emission)
        variance = np.asarray(variance(truth), dtype=np.float64)
        if variance.shape != (obs.n_obs,):
            raise ValueError(f"fisher: variance(brightness) must return shape ({obs.n_obs},), got {variance.shape}")
    variance = np.asarray(variance, dtype=np.float64)
    if variance.ndim not in (0, 1) or (variance.ndim == 1 and variance.shape != (obs.n_obs,)):
        raise ValueError(f"fisher: variance must be a scalar, shape ({obs.n_obs},) or a callable, got shape {variance.shape}")
    if not np.all(np.isfinite(variance) & (variance > 0)):
        raise ValueError("fisher: every variance must be finite and > 0")
    layout = PointBlocks(obs, min_observations=min_observations, inv_var=1.0 / variance)
    sums = brightness_normal_equations(layout, tangent, albedo[layout.point_ids], minnaert_k[layout.point_ids])

    n = obs.n_points
    point = np.full((n, 2, 2), np.nan)
    coupling = np.full((n, 2, 2), np.nan)
    ids = layout.point_ids
    point[ids] = np.stack([np.stack([sums.u11, sums.u12], -1), np.stack([sums.u12, sums.u22], -1)], -2)
    coupling[ids] = np.stack([np.stack([sums.wa1, sums.wa2], -1), np.stack([sums.wb1, sums.wb2], -1)], -2)
    v_aa, v_ab, v_bb = sums.v
    included = np.zeros(n, bool)
    included[ids] = True
    return FisherBlocks(
        light=np.array([[v_aa, v_ab], [v_ab, v_bb]]),
        point=point,
        coupling=coupling,
        included=included,
        light_tangent=tangent,
        n_obs=layout.n_rows,
    )


def cramer_rao_bounds(observations, light_dir_cam, albedo, minnaert_k, variance, *, min_observations: int = 2) -> dict:
    """Cramer-Rao lower bounds on the variances of unbiased estimates, from :func:`fisher_blocks`.

    Arguments as :func:`fisher_blocks`. Returns a dict:

    - ``albedo_var``, ``k_var``, ``albedo_k_cov`` (n_points,): each point's
      marginal bound (what the light's uncertainty passes on included); NaN
      for points left out;
    - ``light_cov`` (2, 2): the bound on the light's tangent coordinates;
    - ``light_std_deg``: the RMS angular error it implies (``core.light_std_deg``);
    - ``light_tangent`` (2,): where it was evaluated.
    """
    blocks = fisher_blocks(observations, light_dir_cam, albedo, minnaert_k, variance, min_observations=min_observations)
    light_cov, var_albedo, var_k, cov_albedo_k = arrow_covariance(*blocks._arrow())
    n = blocks.included.size

    def per_point(values):
        out = np.full(n, np.nan)
        out[blocks.included] = values
        return out

    return {
        "albedo_var": per_point(var_albedo),
        "k_var": per_point(var_k),
        "albedo_k_cov": per_point(cov_albedo_k),
        "light_cov": light_cov,
        "light_std_deg": light_std_deg(blocks.light_tangent, light_cov),
        "light_tangent": blocks.light_tangent,
    }


def _parameters(source, what):
    """(light_dir_cam, albedo, minnaert_k) of a FitResult-like object, a mapping or a 3-tuple."""
    if isinstance(source, Mapping):
        return np.asarray(source["light_dir_cam"], float), np.asarray(source["albedo"], float), np.asarray(source["minnaert_k"], float)
    if isinstance(source, (tuple, list)) and len(source) == 3:
        return tuple(np.asarray(value, float) for value in source)
    try:
        return np.asarray(source.light_dir_cam, float), np.asarray(source.albedo, float), np.asarray(source.minnaert_k, float)
    except AttributeError:
        raise ValueError(f"efficiency: {what} must be a FitResult, a mapping or (light_dir_cam, albedo, minnaert_k)") from None


def efficiency(estimates, truth, bounds: Mapping) -> dict:
    """How close an estimator comes to the Cramer-Rao bound on one data set.

    ``estimates``: a FitResult (or a mapping / tuple with ``light_dir_cam``,
    ``albedo``, ``minnaert_k``); ``truth``: the same for the true values
    (per-point arrays or scalars); ``bounds``: :func:`cramer_rao_bounds`.

    Per-point parameters have a different bound at every point, so the
    efficiency is ``1 / mean_p(err_p**2 / bound_p)``: each squared error in
    units of its own bound, averaged, inverted (``albedo_efficiency``,
    ``k_efficiency``). It is 1 for an efficient unbiased estimator (up to
    the scatter of a mean of n chi-square(1) variables, about ``sqrt(2 /
    n)``) and below 1 for a worse one; bias also lowers it. Also given:
    ``albedo_efficiency_pooled = mean(bound) / mean(err**2)`` (dominated by
    the worst-determined points), and ``n_points`` (points finite in
    estimate and bound).

    Light: ``light_error_deg`` (angle to the truth), ``light_std_deg`` (the
    bound's RMS angular error), ``light_error_sigma`` (their ratio), and
    ``light_mahalanobis = sqrt(d^T C^-1 d)`` with ``d`` the error in tangent
    coordinates and ``C`` the bound: a chi with 2 degrees of freedom for an
    efficient estimator (below 2.45 in 95 % of data sets).
    """
    light_est, albedo_est, k_est = _parameters(estimates, "estimates")
    light_true, albedo_true, k_true = _parameters(truth, "truth")
    out = {}
    finite = np.ones(np.shape(bounds["albedo_var"]), bool)
    for name, est, true, bound in (
        ("albedo", albedo_est, albedo_true, bounds["albedo_var"]),
        ("k", k_est, k_true, bounds["k_var"]),
    ):
        err2 = (np.broadcast_to(est, np.shape(bound)) - np.broadcast_to(true, np.shape(bound))) ** 2
        ok = np.isfinite(err2) & np.isfinite(bound) & (np.asarray(bound) > 0)
        finite &= ok
        out[f"{name}_efficiency"] = float(1.0 / np.mean(err2[ok] / bound[ok])) if np.any(ok) else float("nan")
        out[f"{name}_efficiency_pooled"] = float(np.mean(bound[ok]) / np.mean(err2[ok])) if np.any(ok) else float("nan")
    out["n_points"] = int(np.count_nonzero(finite))
    error_deg = float(angle_between_deg(light_est, light_true))
    light_std = float(bounds["light_std_deg"])
    delta = tangent_from_light(light_est) - tangent_from_light(light_true)
    out["light_error_deg"] = error_deg
    out["light_std_deg"] = light_std
    out["light_error_sigma"] = error_deg / light_std if light_std > 0 else float("inf")
    out["light_mahalanobis"] = float(np.sqrt(delta @ np.linalg.solve(np.asarray(bounds["light_cov"]), delta)))
    return out
