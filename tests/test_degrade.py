"""Image degradations: the PSF's normalisation, width and energy, the gains' statistics, the named conditions."""

import math

import numpy as np
import pytest
from scipy.optimize import curve_fit
from scipy.special import erf

from asteroid_photometry.world import degrade, noise

AMICA = noise.sensor_from_config(noise.PROPOSED_NOISE_LEVELS[1])


def pixel_gaussian(offsets, amplitude, fwhm):
    """A Gaussian of the given FWHM integrated over unit pixels centred at ``offsets`` (1-D)."""
    scale = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0))) * math.sqrt(2.0)  # the FWHM of a Gaussian, written here independently
    return amplitude * 0.5 * (erf((offsets + 0.5) / scale) - erf((offsets - 0.5) / scale))


def fitted_core_fwhm(kernel):
    """FWHM of a pixel-integrated Gaussian fitted to the kernel's central row and column."""
    radius = kernel.shape[0] // 2
    offsets = np.arange(-radius, radius + 1, dtype=float)
    profile = 0.5 * (kernel[radius] + kernel[:, radius])
    (amplitude, fwhm), _ = curve_fit(pixel_gaussian, offsets, profile, p0=(profile.max(), 2.0))
    return abs(fwhm)


@pytest.mark.parametrize("fwhm", [0.8, 1.5, 3.0, 6.0])
def test_kernel_sums_to_one_and_its_core_has_the_fwhm_asked(fwhm):
    kernel = degrade.psf_kernel(fwhm)
    assert kernel.shape[0] == kernel.shape[1] and kernel.shape[0] % 2 == 1
    assert kernel.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(kernel >= 0)
    np.testing.assert_allclose(kernel, kernel.T, atol=1e-15)
    assert fitted_core_fwhm(kernel) == pytest.approx(fwhm, rel=1e-3)


def test_kernel_with_a_halo_keeps_the_core_and_moves_the_energy_asked_into_the_wings():
    fwhm, fraction, halo_fwhm = 1.5, 0.05, 20.0
    plain = degrade.psf_kernel(fwhm, radius_px=100)
    haloed = degrade.psf_kernel(fwhm, fraction, halo_fwhm)
    assert haloed.shape == (201, 201)  # 5 halo FWHMs by default
    assert haloed.sum() == pytest.approx(1.0, abs=1e-12)
    # Outside 4 core FWHMs the core has nothing left: what lies there is the halo's, a power-law tail.
    radius = np.hypot(*np.meshgrid(np.arange(-100, 101), np.arange(-100, 101)))
    outside = radius > 4 * fwhm
    assert plain[outside].sum() < 1e-12
    halo = degrade.moffat_profile(radius, halo_fwhm)
    halo /= halo.sum()
    assert haloed[outside].sum() == pytest.approx(fraction * halo[outside].sum(), rel=1e-9)
    assert 0.8 * fraction < haloed[outside].sum() < fraction  # 13 % of the halo lies within 6 px
    # Far out the halo falls as r**-4 (a Moffat of beta 2), not exponentially.
    assert haloed[100, 100 + 100] / haloed[100, 100 + 80] == pytest.approx(1.25**-4, rel=0.05)
    # The core still dominates the centre, with its width.
    assert fitted_core_fwhm(haloed[90:111, 90:111] - fraction * halo[90:111, 90:111]) == pytest.approx(fwhm, rel=1e-3)


def test_kernel_rejects_bad_arguments():
    for bad in (dict(fwhm_px=-1.0), dict(fwhm_px=float("nan")), dict(fwhm_px=1.0, halo_fraction=1.0), dict(fwhm_px=1.0, halo_fraction=-0.1),
                dict(fwhm_px=1.0, halo_fraction=0.1, halo_fwhm_px=0.0), dict(fwhm_px=1.0, radius_px=-1)):
        with pytest.raises(ValueError):
            degrade.psf_kernel(**bad)
    np.testing.assert_array_equal(degrade.psf_kernel(0.0), np.pad([[1.0]], 1))


def test_convolution_conserves_the_total_away_from_the_borders_and_loses_what_leaves_the_frame():
    rng = np.random.default_rng(4)
    image = np.zeros((256, 300), dtype=np.float32)
    image[60:200, 70:230] = rng.uniform(0.1, 0.7, (140, 160))
    kernel = degrade.psf_kernel(2.0, 0.03, 10.0)  # radius 50: the content is 60 px from every border
    blurred = degrade.apply_psf(image, kernel)
    assert blurred.shape == image.shape and blurred.dtype == np.float32
    assert np.all(blurred >= 0)
    assert float(blurred.astype(np.float64).sum()) == pytest.approx(float(image.astype(np.float64).sum()), rel=1e-6)
    assert not np.allclose(blurred, image, atol=1e-3)
    # The same in float64, to round-off.
    assert degrade.apply_psf(image.astype(np.float64), kernel).sum() == pytest.approx(image.astype(np.float64).sum(), rel=1e-12)
    # A point source lands on its pixel as the kernel itself.
    point = np.zeros((101, 101))
    point[50, 50] = 1.0
    np.testing.assert_allclose(degrade.apply_psf(point, kernel), kernel, atol=1e-15)
    # A source at the border loses the light spread past the frame (the sky beyond is black).
    edge = np.zeros((101, 101))
    edge[50, 0] = 1.0
    assert degrade.apply_psf(edge, kernel).sum() == pytest.approx(kernel[:, 50:].sum(), rel=1e-9)


@pytest.mark.parametrize("sigma", [0.02, 0.3])
def test_gains_are_lognormal_with_the_sigma_asked_and_reproducible(sigma):
    """At sigma 0.3 a 1 + N(0, sigma) gain would put the log's mean at -0.05, 15 of the allowed errors away."""
    n = 200_000
    gains = degrade.exposure_gains(n, sigma, seed=11)
    assert np.all(gains > 0)
    log_gain = np.log(gains)
    # Sampling errors: sigma / sqrt(n) for the mean, sigma / sqrt(2 n) for the std; 5 of them allowed.
    assert abs(log_gain.mean()) < 5 * sigma / math.sqrt(n)
    assert abs(log_gain.std() - sigma) < 5 * sigma / math.sqrt(2 * n)
    assert abs(gains.mean() - math.exp(sigma**2 / 2)) < 5 * gains.std() / math.sqrt(n)
    np.testing.assert_array_equal(degrade.exposure_gains(n, sigma, seed=11), gains)
    assert not np.array_equal(degrade.exposure_gains(n, sigma, seed=12), gains)
    np.testing.assert_array_equal(degrade.exposure_gains(10, sigma, seed=11), gains[:10])
    np.testing.assert_array_equal(degrade.exposure_gains(5, 0.0, seed=1), np.ones(5))
    with pytest.raises(ValueError):
        degrade.exposure_gains(5, -0.1, seed=1)


def test_condition_validation_names_the_bad_key():
    condition = degrade.condition_from_config({"name": "blurred", "psf_fwhm_px": 1.5, "gain_sigma": 0.01, "sensor_level": "amica_12bit"})
    assert condition.psf_fwhm_px == 1.5 and condition.halo_fraction == 0.0 and condition.kernel.sum() == pytest.approx(1.0)
    assert degrade.ImagingCondition("ideal").kernel is None
    for key, value in (("psf_fwhm_px", -1), ("halo_fraction", 1.0), ("halo_fwhm_px", 0), ("gain_sigma", float("nan")),
                       ("prior_sigma_m", -5), ("view_latitude_deg", 95), ("light_out_of_plane_deg", "ten"), ("sensor_level", 3)):
        with pytest.raises(ValueError, match=key):
            degrade.condition_from_config({"name": "bad", key: value})
    with pytest.raises(ValueError, match="psf_fwhm"):
        degrade.condition_from_config({"name": "bad", "psf_fwhm": 1.0})
    with pytest.raises(ValueError, match="name"):
        degrade.condition_from_config({"psf_fwhm_px": 1.0})
    assert degrade.sensor_of(condition, list(noise.PROPOSED_NOISE_LEVELS)) == AMICA
    with pytest.raises(ValueError, match="sensor_level"):
        degrade.sensor_of(degrade.ImagingCondition("x", sensor_level="nope"), list(noise.PROPOSED_NOISE_LEVELS))


def test_degrade_images_applies_psf_then_gain_then_noise_reproducibly():
    image = np.zeros((64, 64))
    image[16:48, 16:48] = 0.4
    images = [image, 0.5 * image, image]
    condition = degrade.ImagingCondition("real", psf_fwhm_px=2.0, gain_sigma=0.05, sensor_level="amica_12bit")
    first, gains = degrade.degrade_images(images, condition, AMICA, seed=7)
    again, gains_again = degrade.degrade_images(images, condition, AMICA, seed=7)
    np.testing.assert_array_equal(gains, gains_again)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(degrade.degrade_images(images, condition, AMICA, seed=8)[0][0], first[0])
    # Without noise: exactly the blurred image times its gain.
    quiet = degrade.ImagingCondition("quiet", psf_fwhm_px=2.0, gain_sigma=0.05)
    clean, clean_gains = degrade.degrade_images(images, quiet, None, seed=7)
    np.testing.assert_array_equal(clean_gains, gains)  # the gains' stream does not depend on the sensor
    kernel = degrade.psf_kernel(2.0)
    for source, result, gain in zip(images, clean, clean_gains):
        np.testing.assert_allclose(result, degrade.apply_psf(source, kernel) * gain, rtol=0, atol=1e-15)
    # With noise: the noisy image scatters about the clean one by the sensor's noise.
    residual = (first[0] - clean[0])[20:44, 20:44]
    expected = math.sqrt(noise.observation_variance(0.4 * gains[0], AMICA))
    assert residual.std() == pytest.approx(expected, rel=0.15)
    # The first image's noise does not depend on how many images follow.
    single, single_gains = degrade.degrade_images(images[:1], condition, AMICA, seed=7)
    assert single_gains[0] == gains[0]
    np.testing.assert_array_equal(single[0], first[0])
    # Each pixel's noise follows that pixel alone: images a relative 1e-6 brighter keep nearly all their codes.
    brighter, _ = degrade.degrade_images([image * (1.0 + 1e-6) for image in images], condition, AMICA, seed=7)
    assert max(np.mean(a != b) for a, b in zip(brighter, first)) < 1e-3
    with pytest.raises(ValueError, match="sensor"):
        degrade.degrade_images(images, condition, None, seed=7)
    with pytest.raises(ValueError, match="sensor"):
        degrade.degrade_images(images, quiet, AMICA, seed=7)
