"""Realistic imaging: what optics and calibration do to a rendered image before the sensor records it.

The renderer (``render``) produces ideal linear radiance images: every pixel
wholly on one flat facet has exactly that facet's brightness. A real camera
adds, in the order light meets it:

1. the point spread function (``psf_kernel``, ``apply_psf``): diffraction,
   defocus and jitter blur the image into a compact core, modelled as a
   Gaussian of a given FWHM, and scattered light inside the optics spreads a
   small fraction of the energy into a wide, faint halo;
2. a per-image multiplicative calibration error (``exposure_gains``): the
   exposure time, the flat field's overall level and the radiometric
   calibration are known to a percent or so per frame, so each image's
   radiance is off by its own factor;
3. the sensor (``noise.apply_sensor_noise``): shot noise, read noise and the
   ADC.

``ImagingCondition`` names one such combination together with the geometry
of the image set it goes with (how far the view leaves the spin equator, how
far the light leaves the plane of the orbit) and the position prior of the
reconstruction; ``degrade_images`` applies its image degradations (1 to 3)
to a list of rendered images, reproducibly from one seed.

Every function here is new: nothing in the rendered sets or the estimators
changes unless a caller applies them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy.special import erf

from asteroid_photometry.world.noise import SensorModel, apply_sensor_noise, sensor_from_config

CONFIG_KEY = "imaging_conditions"

# Gaussian FWHM = this many standard deviations: 2 sqrt(2 ln 2).
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
# The halo's Moffat exponent: a modified Lorentzian (1 + (r/alpha)^2)^-beta.
HALO_MOFFAT_BETA = 2.0
# Default halo width, in pixels, when a halo is asked for without one.
DEFAULT_HALO_FWHM_PX = 20.0
# Default kernel radius: this many FWHMs of the core, or of the halo when there is one.
CORE_RADIUS_FWHM = 3.0
HALO_RADIUS_FWHM = 5.0


# --------------------------------------------------------------------------
# Point spread function
# --------------------------------------------------------------------------


def _pixel_integrated_gaussian_1d(offsets: np.ndarray, sigma: float) -> np.ndarray:
    """The unit Gaussian of standard deviation ``sigma`` integrated over pixels centred at ``offsets``."""
    if sigma == 0.0:
        return (offsets == 0).astype(np.float64)
    scale = sigma * math.sqrt(2.0)
    return 0.5 * (erf((offsets + 0.5) / scale) - erf((offsets - 0.5) / scale))


def moffat_profile(radius_px, fwhm_px: float, beta: float = HALO_MOFFAT_BETA) -> np.ndarray:
    """The (unnormalised) Moffat profile ``(1 + (r / alpha)**2) ** -beta`` of the given FWHM."""
    alpha = fwhm_px / (2.0 * math.sqrt(2.0 ** (1.0 / beta) - 1.0))
    return (1.0 + (np.asarray(radius_px, dtype=np.float64) / alpha) ** 2) ** (-beta)


def psf_kernel(fwhm_px: float, halo_fraction: float = 0.0, halo_fwhm_px: float = DEFAULT_HALO_FWHM_PX, radius_px: int | None = None) -> np.ndarray:
    """A normalised point spread function: a Gaussian core plus an optional scattered-light halo.

    Returns a square float64 array of side ``2 * radius_px + 1`` with the
    centre of the PSF on its centre pixel, summing to 1 (to round-off).

    Core: a circular Gaussian of full width at half maximum ``fwhm_px``
    pixels (``sigma = fwhm / 2.3548``), integrated exactly over each pixel
    (a product of error-function differences). The rendered image is already
    the radiance averaged over each pixel, so the discrete kernel that blurs
    it is the optical PSF averaged over a pixel. ``fwhm_px = 0`` is no blur
    (a delta core).

    Halo: a Moffat profile ``(1 + (r / alpha)**2) ** -2`` (a squared
    Lorentzian) of FWHM ``halo_fwhm_px``, sampled at pixel centres (it is
    many pixels wide, so averaging over a pixel changes it little), carrying
    ``halo_fraction`` of the kernel's energy. A Moffat rather than a second
    Gaussian because scattered light in real optics falls off as a power of
    the distance (here ``r**-4`` far out), not exponentially: its far wings
    carry light from the bright limb a long way across dark sky and into
    shadows, which is what makes stray light matter to photometry; a wide
    Gaussian would have no such wings.

    ``radius_px``: the kernel's half-width; by default 3 core FWHMs without a
    halo and 5 halo FWHMs with one (at least 1). The kernel is truncated
    there and core and halo are each normalised within it before they are
    mixed, so ``halo_fraction`` is exactly the halo's share of the kernel;
    the truncated Moffat tail (about 2 % of a halo's energy beyond 5 FWHMs)
    is dropped, not moved.
    """
    fwhm_px, halo_fraction, halo_fwhm_px = float(fwhm_px), float(halo_fraction), float(halo_fwhm_px)
    if not math.isfinite(fwhm_px) or fwhm_px < 0:
        raise ValueError(f"psf_kernel: fwhm_px must be a finite number >= 0, got {fwhm_px!r}")
    if not 0.0 <= halo_fraction < 1.0:
        raise ValueError(f"psf_kernel: halo_fraction must be in [0, 1), got {halo_fraction!r}")
    if halo_fraction > 0 and not (math.isfinite(halo_fwhm_px) and halo_fwhm_px > 0):
        raise ValueError(f"psf_kernel: halo_fwhm_px must be a finite number > 0, got {halo_fwhm_px!r}")
    if radius_px is None:
        reach = HALO_RADIUS_FWHM * halo_fwhm_px if halo_fraction > 0 else CORE_RADIUS_FWHM * fwhm_px
        radius_px = max(1, int(math.ceil(reach)))
    if isinstance(radius_px, bool) or not isinstance(radius_px, (int, np.integer)) or radius_px < 0:
        raise ValueError(f"psf_kernel: radius_px must be an integer >= 0, got {radius_px!r}")
    offsets = np.arange(-int(radius_px), int(radius_px) + 1, dtype=np.float64)
    core_1d = _pixel_integrated_gaussian_1d(offsets, fwhm_px / FWHM_PER_SIGMA)
    core = np.outer(core_1d, core_1d)
    core /= core.sum()
    if halo_fraction == 0.0:
        return core
    halo = moffat_profile(np.hypot(offsets[:, None], offsets[None, :]), halo_fwhm_px)
    halo /= halo.sum()
    return (1.0 - halo_fraction) * core + halo_fraction * halo


def apply_psf(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """The image convolved with ``kernel`` (same shape; float64 computation, the input's float dtype back).

    Borders: the scene beyond the frame is taken as black (zero), as it is
    for a body against the sky, and light the kernel spreads past the frame
    is lost, as it would be off a real detector. So the total is conserved
    exactly (to round-off) when nothing bright lies within the kernel's
    radius of the border, and falls short by the escaping light otherwise.
    The convolution is ``scipy.signal.fftconvolve`` (mode ``same``, the
    kernel's centre pixel on each output pixel); its round-off leaves
    values of order 1e-16 of the image's maximum where the exact result is
    0, and the few of them below zero are set to 0 so the image stays a
    radiance.
    """
    image = np.asarray(image)
    kernel = np.asarray(kernel, dtype=np.float64)
    if image.ndim != 2:
        raise ValueError(f"apply_psf: expected a 2-D image, got shape {image.shape}")
    if kernel.ndim != 2 or kernel.shape[0] % 2 == 0 or kernel.shape[1] % 2 == 0:
        raise ValueError(f"apply_psf: the kernel must be 2-D with odd sides (a centre pixel), got shape {kernel.shape}")
    if not np.all(np.isfinite(image)):
        raise ValueError("apply_psf: the image has NaN or infinite pixels")
    # Imported here, not at the top: scipy.signal loads scipy.stats (about
    # 0.4 s), and most jobs that import this module only need psf_kernel.
    from scipy.signal import fftconvolve

    blurred = np.maximum(fftconvolve(image.astype(np.float64), kernel, mode="same"), 0.0)
    out_dtype = image.dtype if np.issubdtype(image.dtype, np.floating) else np.float64
    return blurred.astype(out_dtype, copy=False)


# --------------------------------------------------------------------------
# Calibration errors
# --------------------------------------------------------------------------


def exposure_gains(n_images: int, sigma: float, seed) -> np.ndarray:
    """Per-image multiplicative calibration errors: ``exp(N(0, sigma**2))``, lognormal with median 1.

    Lognormal because a gain is positive and an error of x1.02 is as likely
    as one of /1.02; ``sigma`` is thus the standard deviation of the natural
    log of the gain (about the relative error for small sigma), and the mean
    gain is ``exp(sigma**2 / 2)`` (1.00005 at 1 %). ``seed``: anything
    ``numpy.random.default_rng`` takes; the same seed gives the same gains,
    and the first ``n`` gains do not depend on ``n_images`` beyond them.
    ``sigma = 0`` gives ones.
    """
    if isinstance(n_images, bool) or not isinstance(n_images, (int, np.integer)) or n_images < 0:
        raise ValueError(f"exposure_gains: n_images must be an integer >= 0, got {n_images!r}")
    sigma = float(sigma)
    if not math.isfinite(sigma) or sigma < 0:
        raise ValueError(f"exposure_gains: sigma must be a finite number >= 0, got {sigma!r}")
    return np.exp(sigma * np.random.default_rng(seed).standard_normal(int(n_images)))


# --------------------------------------------------------------------------
# Named conditions
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class ImagingCondition:
    """One named imaging condition: optics, calibration, sensor, and the geometry and priors it goes with.

    - ``psf_fwhm_px``: FWHM of the PSF's Gaussian core, pixels (0: no blur);
    - ``halo_fraction``, ``halo_fwhm_px``: the scattered-light halo's share of
      the energy (0: none) and its FWHM (see ``psf_kernel``);
    - ``gain_sigma``: standard deviation of the log of the per-image gain
      (``exposure_gains``; 0: perfect calibration);
    - ``sensor_level``: the name of an entry of the config's ``noise_levels``
      (``noise.sensor_from_config``), or None for noise-free images;
    - ``prior_sigma_m``: standard deviation of the camera position prior
      given to the reconstruction, metres;
    - ``view_latitude_deg``: how far the cameras sit from the body's spin
      equator, degrees (0: the paper's equatorial views);
    - ``light_out_of_plane_deg``: the light's angle out of the plane of the
      views, degrees;
    - ``surface_map``: the name of an entry of the config's ``surface_maps``
      the body is rendered with (albedo and k varying over it), or None for
      the set's one albedo and k.

    The last three describe the image set and its reconstruction, not the
    images' degradation; they travel here so that one name says everything
    a condition changes. Invalid values raise a ValueError naming the key.
    """

    name: str
    psf_fwhm_px: float = 0.0
    halo_fraction: float = 0.0
    halo_fwhm_px: float = DEFAULT_HALO_FWHM_PX
    gain_sigma: float = 0.0
    sensor_level: str | None = None
    prior_sigma_m: float = 0.0
    view_latitude_deg: float = 0.0
    light_out_of_plane_deg: float = 0.0
    surface_map: str | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"config key '{CONFIG_KEY}': name must be a non-empty string, got {self.name!r}")
        where = f"config key '{CONFIG_KEY}', condition {self.name!r}"

        def number(key, low=None, high=None, low_open=False, high_open=False):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
                raise ValueError(f"{where}: {key} must be a finite number, got {value!r}")
            value = float(value)
            below = low is not None and (value <= low if low_open else value < low)
            above = high is not None and (value >= high if high_open else value > high)
            if below or above:
                interval = ("(" if low_open else "[") + f"{low}, {high}" + (")" if high_open else "]")
                raise ValueError(f"{where}: {key} must lie in {interval}, got {value!r}")
            object.__setattr__(self, key, value)

        number("psf_fwhm_px", 0.0, None)
        number("halo_fraction", 0.0, 1.0, high_open=True)
        number("halo_fwhm_px", 0.0, None, low_open=True)
        number("gain_sigma", 0.0, None)
        number("prior_sigma_m", 0.0, None)
        number("view_latitude_deg", -90.0, 90.0)
        number("light_out_of_plane_deg", -90.0, 90.0)
        for key in ("sensor_level", "surface_map"):
            value = getattr(self, key)
            if value is not None and (not isinstance(value, str) or not value):
                raise ValueError(f"{where}: {key} must be a name (of a {'noise level' if key == 'sensor_level' else 'surface map'}) or null, got {value!r}")

    @property
    def kernel(self) -> np.ndarray | None:
        """The condition's PSF kernel, or None when it has no blur."""
        if self.psf_fwhm_px == 0.0 and self.halo_fraction == 0.0:
            return None
        return psf_kernel(self.psf_fwhm_px, self.halo_fraction, self.halo_fwhm_px)


def condition_from_config(entry: dict) -> ImagingCondition:
    """An ``ImagingCondition`` from one config mapping; unknown or missing keys raise a ValueError naming them."""
    if not isinstance(entry, dict):
        raise ValueError(f"config key '{CONFIG_KEY}': each condition must be a mapping, got {entry!r}")
    allowed = {field.name for field in fields(ImagingCondition)}
    where = f"config key '{CONFIG_KEY}'" + (f", condition {entry['name']!r}" if "name" in entry else "")
    unknown = sorted(set(entry) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    if "name" not in entry:
        raise ValueError(f"{where}: missing key(s) ['name']")
    return ImagingCondition(**entry)


def sensor_of(condition: ImagingCondition, noise_levels: list) -> SensorModel | None:
    """The sensor of ``condition.sensor_level`` among the config's ``noise_levels`` entries (None: noise-free)."""
    if condition.sensor_level is None:
        return None
    for level in noise_levels:
        if isinstance(level, dict) and level.get("name") == condition.sensor_level:
            return sensor_from_config(level)
    names = [level.get("name") for level in noise_levels if isinstance(level, dict)]
    raise ValueError(f"config key '{CONFIG_KEY}', condition {condition.name!r}: sensor_level {condition.sensor_level!r} is none of the noise levels {names}")


def degrade_images(images, condition: ImagingCondition, sensor: SensorModel | None, seed) -> tuple[list[np.ndarray], np.ndarray]:
    """The images as ``condition`` records them, and the gain applied to each: ``(images, gains)``.

    In this order, for image ``i``:

    1. PSF: ``apply_psf`` with ``condition.kernel`` (skipped without blur);
    2. gain: multiplied by ``gains[i]`` from ``exposure_gains(len(images),
       condition.gain_sigma, ...)``: the calibration error scales the light
       reaching the sensor, so the sensor's noise follows the scaled signal;
    3. sensor: ``apply_sensor_noise`` with ``sensor`` (skipped when
       ``sensor`` is None, which ``condition.sensor_level`` must then be too;
       ``sensor_of`` finds it by name), its shot noise drawn by the inverse
       CDF: each pixel's count follows that pixel's value alone, so a render
       that differs in its last bits (another processor) gives the same
       images but for a few counts, not another draw of the noise.

    Randomness: ``seed`` (anything ``numpy.random.SeedSequence`` takes)
    spawns one independent stream for the gains and one per image for its
    noise, so the result is a deterministic function of the images, the
    condition, the sensor and the seed, and image ``i``'s noise does not
    depend on how many images follow it. Returns float64 images.
    """
    images = list(images)
    if (sensor is None) != (condition.sensor_level is None):
        raise ValueError(
            f"degrade_images: condition {condition.name!r} has sensor_level {condition.sensor_level!r} "
            f"but the sensor given is {None if sensor is None else (sensor.name or 'unnamed')!r}"
        )
    if sensor is not None and sensor.name and sensor.name != condition.sensor_level:
        raise ValueError(f"degrade_images: condition {condition.name!r} wants sensor level {condition.sensor_level!r}, got {sensor.name!r}")
    gain_stream, *image_streams = np.random.SeedSequence(seed).spawn(len(images) + 1)
    gains = exposure_gains(len(images), condition.gain_sigma, np.random.default_rng(gain_stream))
    kernel = condition.kernel
    degraded = []
    for image, gain, stream in zip(images, gains, image_streams):
        image = np.asarray(image, dtype=np.float64)
        if kernel is not None:
            image = apply_psf(image, kernel)
        if condition.gain_sigma > 0:
            image = image * gain
        if sensor is not None:
            image = apply_sensor_noise(image, sensor, np.random.default_rng(stream), shot_draw="inverse_cdf")
        degraded.append(image)
    return degraded, gains
