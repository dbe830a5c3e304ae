"""Per-image gains: each image's calibration error, estimated against the current photometric model.

Real images carry a multiplicative calibration error per frame (exposure
time, flat-field level; ``world.degrade.exposure_gains`` simulates it): the
brightness of row ``r``, seen in image ``i = image_index[r]``, is
``b_r = g_i * m_r + noise`` with ``m_r`` the model's prediction. Given the
predictions of a current fit (light, albedo, k held fixed), this module
estimates the gains, as shape-from-shading codes do when they float the
exposures (Ames Stereo Pipeline's ``sfs --float-exposure``): alternate a
photometric fit with the gains fixed and a gain fit with the model fixed.

The model in each image is linear in its gain, so the maximum-likelihood
gain for Gaussian noise of known variance ``v_r`` is a weighted least-squares
fit through the origin, ``b_r / sqrt(v_r) ~ g_i * m_r / sqrt(v_r)``, one
small problem per image solved with ``numpy.linalg.lstsq``; its variance is
``1 / sum(m_r**2 / v_r)``. Without variances every row weighs the same and
the variance is scaled by the pooled residual variance.

The gauge. A common factor of all gains trades exactly against the albedo
(every prediction scales with it), so the gains are only known up to one
factor. ``gauge="geometric_mean"`` (the default) divides the gains by their
geometric mean, so that ``prod(g) = 1`` and the albedo keeps the overall
scale; no image is special, and no single image's noise enters every gain.
``gauge="first"`` fixes the first image's gain to 1 instead (its standard
deviation is then 0 and its noise passes to all others). The factor
removed is returned as ``scale``: multiply the albedo by it to keep the
predictions unchanged.

Standard deviations after the gauge come from the unconstrained ones by
first-order propagation in log: with ``s_i`` the standard deviation of
``log g_i``, the geometric-mean gauge gives ``s_i**2 (1 - 2/n) + sum(s_j**2)
/ n**2`` and the first-image gauge ``s_i**2 + s_0**2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from asteroid_photometry.estimation.core import Observations

GAUGES = ("geometric_mean", "first")


@dataclass(frozen=True)
class GainEstimate:
    """The gains of ``estimate_gains``, per image; NaN for images without usable rows.

    ``gains`` and ``std`` are after the gauge; ``scale`` is the common factor
    the gauge removed (the unconstrained gains are ``gains * scale``);
    ``n_rows`` counts each image's rows; ``reduced_chi2`` is the weighted
    residual sum of squares per degree of freedom (near 1 when the given
    variances are right and the model fits).
    """

    gains: np.ndarray
    std: np.ndarray
    scale: float
    n_rows: np.ndarray
    reduced_chi2: float
    gauge: str


def estimate_gains(
    observations: Observations,
    image_index,
    prediction,
    variance=None,
    *,
    gauge: str = "geometric_mean",
    n_images: int | None = None,
) -> GainEstimate:
    """Each image's gain against fixed predictions, with its standard deviation (see the module docstring).

    ``image_index``: int (n_obs,), the image of each row of ``observations``
    (0 .. n_images - 1; ``n_images`` defaults to the largest index + 1).
    ``prediction``: the model's brightness per row at gain 1 (the albedo
    scale it holds is the one kept). ``variance``: the noise variance of each
    row's brightness (e.g. ``world.noise.observation_variance`` of the
    prediction), or None for equal weights with the noise level estimated
    from the residuals. Rows with a prediction <= 0 carry no information on
    the gain and are left out; an image with none left gets NaN and takes
    no part in the gauge (with ``gauge="first"``, image 0 must have rows).
    """
    if gauge not in GAUGES:
        raise ValueError(f"estimate_gains: gauge must be one of {GAUGES}, got {gauge!r}")
    brightness = observations.brightness
    n_obs = observations.n_obs
    image_index = np.asarray(image_index)
    if image_index.shape != (n_obs,) or (n_obs and not np.issubdtype(image_index.dtype, np.integer)):
        raise ValueError(f"estimate_gains: image_index must be integers of shape ({n_obs},), got {image_index.dtype} {image_index.shape}")
    prediction = np.asarray(prediction, dtype=np.float64)
    if prediction.shape != (n_obs,) or not np.all(np.isfinite(prediction)):
        raise ValueError(f"estimate_gains: prediction must be finite, of shape ({n_obs},), got {prediction.shape}")
    known_variance = variance is not None
    if known_variance:
        variance = np.asarray(variance, dtype=np.float64)
        if variance.shape != (n_obs,) or not np.all(np.isfinite(variance) & (variance > 0)):
            raise ValueError(f"estimate_gains: variance must be finite and > 0, of shape ({n_obs},)")
    else:
        variance = np.ones(n_obs)
    if n_obs and image_index.min() < 0:
        raise ValueError(f"estimate_gains: image_index must be >= 0, got {image_index.min()}")
    if n_images is None:
        n_images = int(image_index.max()) + 1 if n_obs else 0
    elif n_obs and image_index.max() >= n_images:
        raise ValueError(f"estimate_gains: image_index reaches {image_index.max()}, beyond n_images = {n_images}")

    usable = prediction > 0
    sigma = np.sqrt(variance)
    gains = np.full(n_images, np.nan)
    unit_variance = np.full(n_images, np.nan)  # variance of each gain for unit residual variance
    n_rows = np.bincount(image_index[usable], minlength=n_images)
    residual_sum = 0.0
    order = np.argsort(image_index, kind="stable")
    bounds = np.searchsorted(image_index[order], np.arange(n_images + 1))
    for image in range(n_images):
        rows = order[bounds[image] : bounds[image + 1]]
        rows = rows[usable[rows]]
        if rows.size == 0:
            continue
        design = (prediction[rows] / sigma[rows])[:, None]
        target = brightness[rows] / sigma[rows]
        solution = np.linalg.lstsq(design, target, rcond=None)[0]
        gains[image] = solution[0]
        unit_variance[image] = 1.0 / float(design[:, 0] @ design[:, 0])
        residual_sum += float(np.sum((target - design[:, 0] * solution[0]) ** 2))
    fitted = np.isfinite(gains)
    dof = int(n_rows.sum()) - int(fitted.sum())
    reduced_chi2 = residual_sum / dof if dof > 0 else float("nan")
    gain_variance = unit_variance * (1.0 if known_variance else reduced_chi2)
    if np.any(gains[fitted] <= 0):
        bad = int(np.flatnonzero(fitted & (gains <= 0))[0])
        raise ValueError(f"estimate_gains: image {bad} fits a gain <= 0 ({gains[bad]:.3g}); the predictions do not describe it")

    log_gain = np.log(gains)
    log_variance = gain_variance / gains**2
    if gauge == "geometric_mean":
        n = int(fitted.sum())
        log_scale = float(np.mean(log_gain[fitted])) if n else float("nan")
        log_variance_after = log_variance * (1.0 - 2.0 / n) + float(np.sum(log_variance[fitted])) / n**2 if n else log_variance
    else:
        if n_images == 0 or not fitted[0]:
            raise ValueError("estimate_gains: gauge 'first' needs rows in image 0")
        log_scale = float(log_gain[0])
        log_variance_after = log_variance + log_variance[0]
        log_variance_after[0] = 0.0
    gains_after = np.exp(log_gain - log_scale)
    std_after = gains_after * np.sqrt(log_variance_after)
    return GainEstimate(gains_after, std_after, float(np.exp(log_scale)), n_rows, float(reduced_chi2), gauge)
