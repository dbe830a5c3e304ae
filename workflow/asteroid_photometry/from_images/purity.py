"""A statistical purity test for bilinear samples of noisy images.

``cloud.sample_pure`` keeps a sample when the four pixels a bilinear sample
reads agree within a fixed relative tolerance (0.1 % in the config). That
suits noise-free renders, where a pixel wholly on one flat facet has
exactly the facet's brightness; on images with sensor noise (1 % per pixel
for an AMICA-like camera) four pure pixels almost never agree to 0.1 %, and
a tolerance wide enough to pass them would pass edges too.

Here the question is asked of the noise model instead: are the four values
``x_j`` consistent with one common brightness ``m``, given each pixel's
noise variance ``v_j``? Under that hypothesis, with Gaussian noise,

    chi2 = sum_j (x_j - m_hat)**2 / v_j,   m_hat = sum_j (x_j / v_j) / sum_j (1 / v_j),

follows a chi-square law with 3 degrees of freedom (four values, one fitted
mean), and the sample is pure when ``chi2`` stays below that law's
``1 - significance`` quantile: a pure sample is then rejected with
probability ``significance``, while a sample straddling an edge, the limb
or a shadow boundary is rejected with a probability that grows with the
step's size in units of the noise.

Variances. With a sensor model (``world.noise.SensorModel``) or a function
of brightness, the hypothesis says the four pixels share one brightness,
hence one variance: it is evaluated at their plain mean, not at each
pixel's own value (which would weigh the pixels that happen to read low
more, biasing the mean low under shot noise), and the weighted mean is the
plain mean. A per-pixel variance map (an array the image's shape) gives
each pixel its own variance. To every variance is added a floor
``(relative_floor * m)**2``: the scatter of the render itself and of the
flat-facet model. On noise-free images (``variance=None``) the floor alone
remains and the test reduces to a tight relative tolerance: with the default
``3e-4`` and ``significance=0.01`` it rejects two pixels more than about
0.1 % above the other two, as the config's ``purity_tolerance: 0.001`` does.

Like ``cloud.sample_pure``, a sample is also rejected where any of its four
pixels reads 0 (sky, or a value clipped at the ADC's bottom) and, with a
sensor model, where any sits at the ADC's top code (saturated): the noise
model does not describe clipped values.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import chdtri

from asteroid_photometry.world.noise import SensorModel, observation_variance, saturated

# Degrees of freedom of the test: four pixels, one common brightness.
DEGREES_OF_FREEDOM = 3
DEFAULT_SIGNIFICANCE = 0.01
# Relative standard deviation added to every pixel's noise (see the module docstring).
DEFAULT_RELATIVE_FLOOR = 3e-4


def bilinear_support(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The four pixels a bilinear sample at ``uv`` reads, (4, n): top-left, top-right, bottom-left, bottom-right.

    The same pixels as ``cloud.sample_pure`` (corner of the top-left pixel at
    (0, 0); positions beyond the outer pixel centres use the border quad);
    their indices are ``pixel_rows_cols``.
    """
    rows, cols = pixel_rows_cols(image.shape, uv)
    return image[rows, cols]


def pixel_rows_cols(shape, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices, each (4, n), of the pixels of ``bilinear_support``."""
    height, width = shape
    uv = np.asarray(uv, dtype=np.float64)
    col = np.clip(np.floor(uv[:, 0] - 0.5).astype(int), 0, width - 2)
    row = np.clip(np.floor(uv[:, 1] - 0.5).astype(int), 0, height - 2)
    rows = np.stack([row, row, row + 1, row + 1])
    cols = np.stack([col, col + 1, col, col + 1])
    return rows, cols


def purity_statistic(image: np.ndarray, uv: np.ndarray, variance=None, relative_floor: float = DEFAULT_RELATIVE_FLOOR):
    """``(mean, chi2)`` per sample: the inverse-variance-weighted mean of the four pixels and their chi-square about it.

    ``variance``: a ``SensorModel`` (its ``observation_variance``), a
    function of brightness returning the noise variance, an array of the
    image's shape holding each pixel's variance, or None for noise-free
    images (the floor alone). ``relative_floor`` > 0 unless every variance
    is positive. NaN ``chi2`` where the variance is 0 (a zero mean with no
    noise).
    """
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 2 or min(image.shape) < 2:
        raise ValueError(f"purity: expected a 2-D image of at least 2x2 pixels, got shape {image.shape}")
    relative_floor = float(relative_floor)
    if not relative_floor >= 0:
        raise ValueError(f"purity: relative_floor must be >= 0, got {relative_floor!r}")
    rows, cols = pixel_rows_cols(image.shape, uv)
    support = image[rows, cols]
    plain_mean = support.mean(axis=0)
    floor = (relative_floor * plain_mean) ** 2
    if variance is None:
        pixel_variance = np.broadcast_to(floor, support.shape)
    elif isinstance(variance, SensorModel):
        pixel_variance = np.broadcast_to(observation_variance(plain_mean, variance) + floor, support.shape)
    elif callable(variance):
        pixel_variance = np.broadcast_to(np.asarray(variance(plain_mean), dtype=np.float64) + floor, support.shape)
    else:
        variance_map = np.asarray(variance, dtype=np.float64)
        if variance_map.shape != image.shape:
            raise ValueError(f"purity: a variance map must have the image's shape {image.shape}, got {variance_map.shape}")
        pixel_variance = variance_map[rows, cols] + floor
    if np.any(pixel_variance < 0):
        raise ValueError("purity: negative variance")
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = 1.0 / pixel_variance
        mean = np.sum(weight * support, axis=0) / np.sum(weight, axis=0)
        chi2 = np.sum(weight * (support - mean) ** 2, axis=0)
    # Equal variances (the sensor-model case): the weighted mean is the plain mean.
    mean = np.where(np.isfinite(mean), mean, plain_mean)
    return mean, chi2


def sample_pure(image: np.ndarray, uv: np.ndarray, variance=None, significance: float = DEFAULT_SIGNIFICANCE, relative_floor: float = DEFAULT_RELATIVE_FLOOR) -> np.ndarray:
    """The image at ``uv`` where the four pixels pass the chi-square test of one common brightness, else 0.

    The call of ``cloud.sample_pure`` with the tolerance replaced by the
    noise model (``variance``, as in ``purity_statistic``) and the
    probability ``significance`` of rejecting a pure sample. Returns the
    inverse-variance-weighted mean of the four pixels where pure.
    """
    significance = float(significance)
    if not 0.0 < significance < 1.0:
        raise ValueError(f"purity: significance must lie in (0, 1), got {significance!r}")
    mean, chi2 = purity_statistic(image, uv, variance, relative_floor)
    threshold = _chi2_threshold(significance)
    support = bilinear_support(np.asarray(image), uv)
    pure = (chi2 <= threshold) & (support.min(axis=0) > 0) & (mean > 0)
    if isinstance(variance, SensorModel):
        pure &= ~np.any(saturated(support, variance), axis=0)
    return np.where(pure, mean, 0.0)


@lru_cache(maxsize=16)
def _chi2_threshold(significance: float) -> float:
    """The chi-square that a pure sample exceeds with probability ``significance`` (the refinement asks it hundreds of
    times a set, at one significance)."""
    return float(chdtri(DEGREES_OF_FREEDOM, significance))


class PurityTest:
    """The statistical purity test of one sensor as a callable ``test(image, uv)``: ``sample_pure`` with its noise model.

    What the refinement and the cloud's sampling take in place of a relative
    tolerance when the images come with a sensor model. ``sample_variance``
    is the noise variance of one pure sample (the mean of four pixels) at
    brightness ``b``, floor included.
    """

    def __init__(self, sensor: SensorModel, significance: float = DEFAULT_SIGNIFICANCE, relative_floor: float = DEFAULT_RELATIVE_FLOOR):
        self.sensor, self.significance, self.relative_floor = sensor, float(significance), float(relative_floor)

    def __call__(self, image: np.ndarray, uv: np.ndarray) -> np.ndarray:
        return sample_pure(image, uv, variance=self.sensor, significance=self.significance, relative_floor=self.relative_floor)

    def sample_variance(self, brightness) -> np.ndarray:
        brightness = np.asarray(brightness, dtype=np.float64)
        return observation_variance(brightness, self.sensor) / 4.0 + (self.relative_floor * brightness) ** 2
