"""The chi-square purity test of bilinear samples: its false-rejection rate, its power at an edge, its noise-free limit."""

import numpy as np
import pytest

from asteroid_photometry.from_images import cloud, purity
from asteroid_photometry.world import noise

LEVELS = {level["name"]: noise.sensor_from_config(level) for level in noise.PROPOSED_NOISE_LEVELS}
AMICA = LEVELS["amica_12bit"]


def quad_image(values):
    """Quads side by side in a 2-row image, (n, 4) values as top-left, top-right, bottom-left, bottom-right; and the uv of each quad's centre."""
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    image = np.zeros((2, 2 * n))
    image[0, 0::2], image[0, 1::2], image[1, 0::2], image[1, 1::2] = values.T
    uv = np.column_stack([2.0 * np.arange(n) + 1.0, np.ones(n)])
    return image, uv


def noisy_quads(brightness, sensor, rng, step=0.0, n_bright=0):
    """Quads of one true brightness per quad, ``n_bright`` of the four pixels ``1 + step`` times brighter, through the sensor."""
    truth = np.repeat(np.asarray(brightness, dtype=np.float64)[:, None], 4, axis=1)
    truth[:, :n_bright] *= 1.0 + step
    return quad_image(noise.apply_sensor_noise(truth, sensor, rng))


def test_support_is_the_four_pixels_cloud_sample_pure_reads():
    rng = np.random.default_rng(0)
    image = rng.uniform(0.1, 0.5, (7, 9))
    uv = np.column_stack([rng.uniform(-1.0, 10.0, 200), rng.uniform(-1.0, 8.0, 200)])  # borders included
    support = purity.bilinear_support(image, uv)
    assert support.shape == (4, 200)
    # cloud.sample_pure returns the mean of its four pixels; with a tolerance that passes everything, it is theirs.
    np.testing.assert_allclose(cloud.sample_pure(image, uv, 10.0), support.mean(axis=0), rtol=1e-12)
    # And the noise-free test agrees with it where the quads are pure.
    image[2:5, 3:7] = 0.25
    inside = np.column_stack([rng.uniform(4.0, 6.0, 50), rng.uniform(3.0, 4.0, 50)])
    np.testing.assert_allclose(purity.sample_pure(image, inside), cloud.sample_pure(image, inside, 0.001), rtol=1e-12)
    assert np.all(purity.sample_pure(image, inside) == 0.25)


@pytest.mark.parametrize("level", sorted(LEVELS))
def test_pure_quads_are_accepted_at_one_minus_alpha(level):
    """20,000 pure quads (brightness uniform in 0.1 .. 0.6) per sensor: accepted at 0.99 within 0.005 (7 sampling sigmas).

    Measured at seed 1: 0.9901 (scientific_16bit), 0.9904 (amica_12bit),
    0.9903 (amica_12bit_underexposed); at significance 0.001: 0.9992,
    0.9992, 0.9995. The 0.1 % tolerance of ``cloud.sample_pure`` accepts
    0.39 %, 0.02 % and 0.02 % of the same quads.
    """
    sensor = LEVELS[level]
    rng = np.random.default_rng(1)
    brightness = rng.uniform(0.1, 0.6, 20_000)
    image, uv = noisy_quads(brightness, sensor, rng)
    values = purity.sample_pure(image, uv, sensor, significance=0.01)
    accepted = values > 0
    assert accepted.mean() == pytest.approx(0.99, abs=0.005)
    # Where pure, the value is the four pixels' mean (equal variances), an unbiased brightness.
    np.testing.assert_allclose(values[accepted], purity.bilinear_support(image, uv).mean(axis=0)[accepted], rtol=1e-12)
    relative_error = values[accepted] / brightness[accepted] - 1.0
    assert abs(relative_error.mean()) < 4 * relative_error.std() / np.sqrt(accepted.sum())
    assert (cloud.sample_pure(image, uv, 0.001) > 0).mean() < 0.005
    # A looser significance rejects fewer.
    assert (purity.sample_pure(image, uv, sensor, significance=0.001) > 0).mean() == pytest.approx(0.999, abs=0.002)


def test_quads_straddling_a_five_percent_step_are_rejected_at_the_amica_level():
    """A 5 % brightness step through 20,000 quads at b = 0.35 (each pixel's noise 1 %) under the AMICA-like sensor.

    Measured rejection at seed 2: 0.967 with two pixels on each side and
    0.887 with one pixel on the bright side (the test asks at least 0.93 and
    0.83). At b = 0.1 (noise 1.9 %) the same step is rejected 0.32 of the
    time, and at b = 0.35 under the underexposed sensor (3.6 % noise) 0.065:
    a step is found when it is a few times the per-pixel noise.
    """
    rng = np.random.default_rng(2)
    brightness = np.full(20_000, 0.35)
    for n_bright, least in ((2, 0.93), (1, 0.83)):
        image, uv = noisy_quads(brightness, AMICA, rng, step=0.05, n_bright=n_bright)
        rejected = (purity.sample_pure(image, uv, AMICA) == 0).mean()
        assert rejected >= least, (n_bright, rejected)
    # The power depends on the step in units of the noise: the dim case is rejected much less often.
    image, uv = noisy_quads(np.full(20_000, 0.1), AMICA, rng, step=0.05, n_bright=2)
    assert 0.15 < (purity.sample_pure(image, uv, AMICA) == 0).mean() < 0.5


def test_noise_free_images_reduce_to_a_tight_relative_test():
    """Without noise the floor (3e-4 relative) alone decides: steps over about 0.1 % are rejected, render jitter of 1e-5 is not."""
    rng = np.random.default_rng(3)
    brightness = rng.uniform(0.1, 0.6, 1000)
    exact = np.repeat(brightness[:, None], 4, axis=1)
    for values, expect_pure in (
        (exact, True),
        (exact * (1.0 + 1e-5 * rng.standard_normal(exact.shape)), True),
        (exact * np.array([1.0008, 1.0008, 1.0, 1.0]), True),
        (exact * np.array([1.0012, 1.0012, 1.0, 1.0]), False),
        (exact * np.array([1.002, 1.0, 1.0, 1.0]), False),
    ):
        image, uv = quad_image(values)
        result = purity.sample_pure(image, uv, None)
        assert np.all((result > 0) == expect_pure)
        if expect_pure:
            np.testing.assert_allclose(result, values.mean(axis=1), rtol=1e-12)
    # A zero floor with no noise model leaves no variance: nothing is called pure.
    image, uv = quad_image(exact)
    assert np.all(purity.sample_pure(image, uv, None, relative_floor=0.0) == 0)


def test_variance_map_weights_each_pixel_and_callable_matches_the_sensor():
    values = np.array([[0.30, 0.30, 0.30, 0.36]])
    image, uv = quad_image(values)
    # The fourth pixel is known to be noisy: it is down-weighted and the quad stays pure.
    variance_map = np.full(image.shape, 1e-6)
    variance_map[1, 1] = 1e-2
    mean, chi2 = purity.purity_statistic(image, uv, variance_map, relative_floor=0.0)
    weights = 1.0 / np.array([1e-6, 1e-6, 1e-6, 1e-2])
    expected_mean = np.sum(weights * values[0]) / weights.sum()
    assert mean[0] == pytest.approx(expected_mean, rel=1e-12)
    assert chi2[0] == pytest.approx(np.sum(weights * (values[0] - expected_mean) ** 2), rel=1e-12)
    assert purity.sample_pure(image, uv, variance_map, relative_floor=0.0)[0] == pytest.approx(expected_mean)
    # The same quad with equal small variances is an edge.
    assert purity.sample_pure(image, uv, np.full(image.shape, 1e-6))[0] == 0.0
    # A function of brightness gives the sensor model's answer.
    rng = np.random.default_rng(5)
    image, uv = noisy_quads(rng.uniform(0.1, 0.6, 500), AMICA, rng)
    np.testing.assert_array_equal(
        purity.sample_pure(image, uv, lambda b: noise.observation_variance(b, AMICA)), purity.sample_pure(image, uv, AMICA)
    )


def test_zero_and_saturated_pixels_are_never_pure_and_bad_arguments_are_refused():
    top = noise.saturated(np.array([10.0]), AMICA)  # sanity: the sensor saturates
    assert top[0]
    full = AMICA.max_code * AMICA.electrons_per_dn / AMICA.gain_e_per_radiance
    image, uv = quad_image([[0.0, 0.0, 0.0, 0.0], [full, full, full, full], [0.3, 0.3, 0.3, 0.3]])
    np.testing.assert_array_equal(purity.sample_pure(image, uv, AMICA), [0.0, 0.0, 0.3])
    for bad in (dict(significance=0.0), dict(significance=1.0), dict(relative_floor=-1.0)):
        with pytest.raises(ValueError):
            purity.sample_pure(image, uv, AMICA, **bad)
    with pytest.raises(ValueError, match="shape"):
        purity.sample_pure(image, uv, np.ones((3, 3)))
