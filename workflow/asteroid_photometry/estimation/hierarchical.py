"""The light with a k per point held near the body's k, and a gain per image: the light step under a sensor.

Under a camera's noise and calibration error (``docs/table2.md``, section 11)
neither of the refinement's two simpler light fits is right:

- one k for the body (``koizumi.fit_pooled_k``) makes the light take up the
  variation of k over a real surface (about 2 degrees for k varying by 0.1);
- a free k per point leaves the light's elevation nearly a gauge freedom,
  so the per-image calibration errors (2 % under ``amica``) move it by degrees.

Here each point's k is free but held to the body's k by a Gaussian prior of
standard deviation ``k_prior_sd`` (the body's k is fitted with them), and each
image's gain is fitted with the prior the mission states for it
(``gain_sigma``), their geometric mean held at 1 (it trades exactly against the
albedo). The fit is in log brightness, each row weighted by its relative noise:

    log b_pj = log g_j + log A_p + k_p log cos_i + (k_p - 1) log cos_o,
    residuals  (log b - model) / s_pj,  (k_p - k_body) / k_prior_sd,  log g_j / gain_sigma,

solved by ``scipy.optimize.least_squares`` (trf, exact sparse Jacobian). It
returns the light, each point's albedo and k, the body's k and the gains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse

from asteroid_photometry.estimation.core import light_from_tangent, Observations, tangent_from_light

#: Weight of the row that holds the log gains' sum at 0 (the gauge), relative to a residual of one sigma.
GAUGE_WEIGHT = 1e3


@dataclass(frozen=True)
class HierarchicalFit:
    """The light (camera frame), per-point albedo and k (NaN where unfitted), the body's k, and the per-image
    gains (``gains[image]``, 1 where an image has no rows or no gain was fitted)."""

    light_dir_cam: np.ndarray
    albedo: np.ndarray
    minnaert_k: np.ndarray
    body_k: float
    gains: np.ndarray
    n_obs: int
    cost: float


def fit_light_k_prior(
    obs: Observations, image_index, light_init, minnaert_k_init: float, *, relative_sd, k_prior_sd: float, gain_sigma: float = 0.0,
    n_images: int | None = None, min_observations: int = 2, min_cos_incidence: float = 0.05, max_nfev: int = 100,
) -> HierarchicalFit:
    """The fit of the module docstring on the rows of ``obs`` lit at more than ``min_cos_incidence`` under ``light_init``.

    ``image_index``: the image of each row; ``relative_sd``: each row's noise standard deviation over its
    brightness (scalar or per row); ``gain_sigma`` 0 fits no gains. Points with fewer than ``min_observations``
    such rows are left out (NaN).
    """
    image_index = np.asarray(image_index, dtype=np.int64)
    relative_sd = np.broadcast_to(np.asarray(relative_sd, dtype=np.float64), (obs.n_obs,))
    if image_index.shape != (obs.n_obs,):
        raise ValueError(f"fit_light_k_prior: image_index must have one entry per row ({obs.n_obs}), got shape {image_index.shape}")
    if not (k_prior_sd > 0 and np.all(relative_sd > 0) and gain_sigma >= 0):
        raise ValueError("fit_light_k_prior: k_prior_sd and relative_sd must be > 0 and gain_sigma >= 0")
    n_images = int(image_index.max()) + 1 if n_images is None else int(n_images)
    light_init = np.asarray(light_init, dtype=np.float64) / np.linalg.norm(light_init)
    cos_o = np.einsum("ij,ij->i", obs.normal_cam, obs.view_cam)
    use = (obs.normal_cam @ light_init > min_cos_incidence) & (obs.brightness > 0) & (cos_o > 0)
    counts = np.bincount(obs.point_index[use], minlength=obs.n_points)
    use &= counts[obs.point_index] >= min_observations
    points, point_col = np.unique(obs.point_index[use], return_inverse=True)
    images, image_col = np.unique(image_index[use], return_inverse=True)
    m, n_img, rows = len(points), len(images) if gain_sigma > 0 else 0, int(np.count_nonzero(use))
    if m == 0 or rows < 2 * m + 3:
        raise ValueError(f"fit_light_k_prior: {rows} usable observations of {m} points cannot determine the light")
    normal, log_b, log_cos_o, weight = obs.normal_cam[use], np.log(obs.brightness[use]), np.log(cos_o[use]), 1.0 / relative_sd[use]
    # Parameters: light tangent (2), log albedo (m), k (m), body k (1), log gain (n_img).
    k_col, body_col, gain_col = 2 + m, 2 + 2 * m, 3 + 2 * m
    n_par = gain_col + n_img
    row = np.arange(rows)

    def split(x):
        return x[:2], x[2:k_col], x[k_col:body_col], x[body_col], x[gain_col:]

    def residuals(x):
        tangent, log_albedo, k, body_k, log_gain = split(x)
        cos_i = np.maximum(normal @ light_from_tangent(tangent), 1e-3)
        model = log_albedo[point_col] + k[point_col] * np.log(cos_i) + (k[point_col] - 1.0) * log_cos_o
        parts = [weight * (log_b - model - (log_gain[image_col] if n_img else 0.0)), (k - body_k) / k_prior_sd]
        if n_img:
            parts += [log_gain / gain_sigma, [GAUGE_WEIGHT * np.sum(log_gain)]]
        return np.concatenate(parts)

    def jacobian(x):
        tangent, _, k, _, _ = split(x)
        cos_i = np.maximum(normal @ light_from_tangent(tangent), 1e-3)
        step = 1e-7
        d_light = [(light_from_tangent(tangent + step * e) - light_from_tangent(tangent - step * e)) / (2 * step) for e in np.eye(2)]
        entries = [
            (row, np.zeros(rows, int), -weight * k[point_col] * (normal @ d_light[0]) / cos_i),
            (row, np.ones(rows, int), -weight * k[point_col] * (normal @ d_light[1]) / cos_i),
            (row, 2 + point_col, -weight),
            (row, k_col + point_col, -weight * (np.log(cos_i) + log_cos_o)),
            (rows + np.arange(m), k_col + np.arange(m), np.full(m, 1.0 / k_prior_sd)),
            (rows + np.arange(m), np.full(m, body_col), np.full(m, -1.0 / k_prior_sd)),
        ]
        n_res = rows + m
        if n_img:
            entries += [
                (row, gain_col + image_col, -weight),
                (n_res + np.arange(n_img), gain_col + np.arange(n_img), np.full(n_img, 1.0 / gain_sigma)),
                (np.full(n_img, n_res + n_img), gain_col + np.arange(n_img), np.full(n_img, GAUGE_WEIGHT)),
            ]
            n_res += n_img + 1
        r, c, v = (np.concatenate(part) for part in zip(*entries))
        return scipy.sparse.csr_matrix((v, (r, c)), shape=(n_res, n_par))

    cos_i0 = np.maximum(normal @ light_init, 1e-3)
    start_albedo = np.bincount(point_col, weight**2 * (log_b - minnaert_k_init * np.log(cos_i0) - (minnaert_k_init - 1.0) * log_cos_o), m)
    start_albedo /= np.bincount(point_col, weight**2, m)
    x0 = np.concatenate([tangent_from_light(light_init), start_albedo, np.full(m + 1, minnaert_k_init), np.zeros(n_img)])
    solution = scipy.optimize.least_squares(residuals, x0, jac=jacobian, method="trf", x_scale="jac", tr_solver="lsmr", max_nfev=max_nfev)
    tangent, log_albedo, k, body_k, log_gain = split(solution.x)
    albedo, minnaert_k = np.full(obs.n_points, np.nan), np.full(obs.n_points, np.nan)
    albedo[points], minnaert_k[points] = np.exp(log_albedo), k
    gains = np.ones(n_images)
    if n_img:
        gains[images] = np.exp(log_gain)
    return HierarchicalFit(light_from_tangent(tangent), albedo, minnaert_k, float(body_k), gains, rows, float(solution.cost))
