"""The sensor noise model: validation, determinism, clipping, and its variance against simulation."""

import numpy as np
import pandas as pd
import pytest
from scipy.stats import poisson

from asteroid_photometry.world import noise

AMICA = noise.SensorModel(full_well_e=30000, read_noise_e=20, bit_depth=12)


def test_noiseless_deep_sensor_returns_the_input():
    """A huge well (negligible shot noise), no read noise and 32 bits: the image comes back."""
    sensor = noise.SensorModel(full_well_e=1e15, read_noise_e=0.0, bit_depth=32)
    image = np.random.default_rng(1).uniform(0.0, 1.0, size=(64, 48))
    image[:5] = 0.0
    noisy = noise.apply_sensor_noise(image, sensor, np.random.default_rng(2))
    assert noisy.shape == image.shape and noisy.dtype == np.float64
    assert np.abs(noisy - image).max() < 1e-6
    assert np.all(noisy[:5] == 0.0)


def test_quantisation_only_is_within_half_a_step():
    sensor = noise.SensorModel(full_well_e=1e15, read_noise_e=0.0, bit_depth=8)
    image = np.linspace(0.0, 1.0, 1001)
    noisy = noise.apply_sensor_noise(image, sensor, np.random.default_rng(0))
    assert np.abs(noisy - image).max() <= 0.5 * sensor.quantisation_step + 1e-9
    assert len(np.unique(noisy)) == 256


def test_deterministic_given_the_generator():
    image = np.full((32, 32), 0.4)
    first = noise.apply_sensor_noise(image, AMICA, np.random.default_rng(7))
    again = noise.apply_sensor_noise(image, AMICA, np.random.default_rng(7))
    other = noise.apply_sensor_noise(image, AMICA, np.random.default_rng(8))
    assert np.array_equal(first, again)
    assert not np.array_equal(first, other)
    assert np.array_equal(noise.apply_sensor_noise(image, AMICA, 7), first)  # a seed works too


def test_saturation_and_black_are_clipped():
    sensor = noise.SensorModel(full_well_e=30000, read_noise_e=20, bit_depth=12, radiance_at_full_well=2.0)
    bright = noise.apply_sensor_noise(np.full(1000, 5.0), sensor, np.random.default_rng(0))
    assert np.all(bright == 2.0) and noise.saturated(bright, sensor).all()
    assert not noise.saturated(noise.apply_sensor_noise(np.full(1000, 1.9), sensor, np.random.default_rng(0)), sensor).any()
    dark = noise.apply_sensor_noise(np.zeros(100000), sensor, np.random.default_rng(0))
    assert dark.min() == 0.0 and dark.max() > 0.0  # read noise, clipped at code 0
    negative = noise.apply_sensor_noise(np.full(10, -1.0), sensor, np.random.default_rng(0))
    assert negative.min() >= 0.0


# (sensor, brightnesses): the proposed sweep, and a coarse 6-bit ADC where quantisation is an
# eighth of the variance (the other noise is 0.8 steps: the uniform-error model still holds).
COARSE = noise.SensorModel(full_well_e=30000, read_noise_e=360, bit_depth=6, name="coarse_6bit")
CASES = [(noise.sensor_from_config(level), (0.02, 0.1, 0.35, 0.7)) for level in noise.PROPOSED_NOISE_LEVELS]
CASES.append((COARSE, (0.1, 0.37, 0.5)))


@pytest.mark.parametrize("shot_draw", noise.SHOT_DRAWS)
@pytest.mark.parametrize("sensor, brightnesses", CASES, ids=lambda case: getattr(case, "name", ""))
def test_observation_variance_matches_simulation(sensor, brightnesses, shot_draw):
    n = 200_000
    rng = np.random.default_rng(12345)
    for brightness in brightnesses:
        samples = noise.apply_sensor_noise(np.full(n, brightness), sensor, rng, shot_draw=shot_draw)
        predicted = noise.observation_variance(brightness, sensor)
        empirical = samples.var()
        # The sample variance of n draws scatters by about sqrt(2 / n) = 0.3 % relative.
        assert empirical == pytest.approx(predicted, rel=0.02), (sensor.name, brightness)
        # Unbiased away from the clips.
        assert abs(samples.mean() - brightness) < 5 * np.sqrt(predicted / n), (sensor.name, brightness)


UNDEREXPOSED = noise.sensor_from_config(noise.PROPOSED_NOISE_LEVELS[2])


@pytest.mark.parametrize(
    "term, sensor, brightness",
    [("shot", AMICA, 0.35), ("read", UNDEREXPOSED, 0.1), ("quantisation", COARSE, 0.1)],
)
def test_variance_check_can_fail(term, sensor, brightness):
    """Each term is needed: without it the prediction misses the simulation where that term matters."""
    gain = sensor.gain_e_per_radiance
    empirical = noise.apply_sensor_noise(np.full(200_000, brightness), sensor, np.random.default_rng(3)).var()
    full = noise.observation_variance(brightness, sensor)
    term_variance = {
        "shot": brightness / gain,
        "read": (sensor.read_noise_e / gain) ** 2,
        "quantisation": sensor.quantisation_step**2 / 12,
    }[term]
    assert empirical == pytest.approx(full, rel=0.02)
    assert abs(empirical / (full - term_variance) - 1) > 0.1


def test_observation_variance_is_vectorised():
    brightness = np.array([[0.1, 0.2], [0.3, 0.4]])
    variance = noise.observation_variance(brightness, AMICA)
    assert variance.shape == (2, 2)
    assert np.all(np.diff(variance.ravel()) > 0)


def test_proposed_sweep_noise_levels_as_documented():
    """Relative noise at b = 0.35 of the three proposed levels: 0.31 %, 0.99 %, 3.6 % (module docstring)."""
    sensors = [noise.sensor_from_config(level) for level in noise.PROPOSED_NOISE_LEVELS]
    relative = [np.sqrt(noise.observation_variance(0.35, sensor)) / 0.35 for sensor in sensors]
    assert relative == pytest.approx([0.0031, 0.0099, 0.036], rel=0.03)
    assert [sensor.bit_depth for sensor in sensors][1:] == [12, 12]  # AMICA digitises to 12 bits


def test_sensor_from_config_round_trip():
    level = {"name": "amica_12bit", "full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12.0}
    sensor = noise.sensor_from_config(level)
    assert sensor == noise.SensorModel(30000.0, 20.0, 12, 1.0, "amica_12bit")
    assert isinstance(sensor.bit_depth, int)
    assert noise.sensor_from_config(sensor.to_dict()) == sensor
    assert sensor.electrons_per_dn == pytest.approx(30000 / 4095)


@pytest.mark.parametrize(
    "level, message",
    [
        ({"full_well_e": 0, "read_noise_e": 20, "bit_depth": 12}, "full_well_e"),
        ({"full_well_e": 3e4, "read_noise_e": -1, "bit_depth": 12}, "read_noise_e"),
        ({"full_well_e": 3e4, "read_noise_e": 20, "bit_depth": 12.5}, "bit_depth"),
        ({"full_well_e": 3e4, "read_noise_e": 20, "bit_depth": 0}, "bit_depth"),
        ({"full_well_e": 3e4, "read_noise_e": 20, "bit_depth": True}, "bit_depth"),
        ({"full_well_e": 3e4, "read_noise_e": 20, "bit_depth": 12, "radiance_at_full_well": 0}, "radiance_at_full_well"),
        ({"full_well_e": "many", "read_noise_e": 20, "bit_depth": 12}, "full_well_e"),
        ({"full_well_e": float("nan"), "read_noise_e": 20, "bit_depth": 12}, "full_well_e"),
        ({"full_well_e": 3e4, "bit_depth": 12}, "read_noise_e"),
        ({"full_well_e": 3e4, "read_noise_e": 20, "bit_depth": 12, "gain": 2}, "gain"),
    ],
)
def test_bad_levels_are_refused_naming_the_field_and_config_key(level, message):
    with pytest.raises(ValueError, match=message) as error:
        noise.sensor_from_config({"name": "bad", **level})
    assert "noise_levels" in str(error.value) and "'bad'" in str(error.value)


def test_bad_image_is_refused():
    with pytest.raises(ValueError, match="NaN"):
        noise.apply_sensor_noise(np.array([0.1, np.nan]), AMICA, np.random.default_rng(0))
    with pytest.raises(ValueError, match="shot_draw must be one of"):
        noise.apply_sensor_noise(np.array([0.1]), AMICA, np.random.default_rng(0), shot_draw="ppf")


def test_poisson_quantile_is_the_poisson_laws_quantile():
    """The same counts as scipy's quantile function, at means from none to a saturated well's."""
    rng = np.random.default_rng(4)
    means = np.concatenate([np.zeros(50), rng.uniform(0.0, 1.0, 500), rng.uniform(1.0, 50.0, 2000), rng.uniform(50.0, 120_000.0, 5000)])
    uniforms = rng.random(means.size)
    uniforms[:3] = 0.0
    counts = noise.poisson_quantile(means, uniforms)
    # (scipy's quantile of 0 is -1, below the support; a count is 0 there.)
    np.testing.assert_array_equal(counts[3:], poisson.ppf(uniforms[3:], means[3:]))
    assert np.all(counts[:50] == 0.0)
    with pytest.raises(ValueError, match="means but"):
        noise.poisson_quantile(means[:5], uniforms[:4])


@pytest.mark.parametrize("mean", [0.3, 4.0, 37.5, 2500.0])
def test_poisson_quantile_of_uniforms_is_a_poisson_draw(mean):
    """Mean and variance both the mean, within their sampling error (5 standard errors)."""
    n = 400_000
    counts = noise.poisson_quantile(np.full(n, mean), np.random.default_rng(9).random(n))
    assert abs(counts.mean() - mean) < 5 * np.sqrt(mean / n)
    # The variance's standard error: sqrt((2 mean^2 + mean) / n) for the Poisson law (its fourth cumulant is the mean).
    assert abs(counts.var() - mean) < 5 * np.sqrt((2 * mean**2 + mean) / n)


def test_inverse_cdf_counts_follow_their_own_pixel():
    """Renders differing in their last digits (a relative 1e-6 on a fifth of the pixels, about what another
    processor's vector width gives) keep nearly every count of the inverse-CDF draw; numpy's sampler, whose use of
    the generator depends on each mean, falls out of step on some images and redraws the rest of them."""
    rng = np.random.default_rng(11)
    changed = {shot_draw: [] for shot_draw in noise.SHOT_DRAWS}
    for seed in range(12):
        image = rng.uniform(0.0, 0.9, (128, 128))
        image[:, :40] = 0.0  # sky
        image[:, 40:50] = rng.uniform(0.0, 3e-4, (128, 10))  # a blurred limb's tail: under 10 electrons
        moved = image * (1.0 + 1e-6 * (rng.random(image.shape) < 0.2))
        for shot_draw in noise.SHOT_DRAWS:
            first = noise.apply_sensor_noise(image, AMICA, seed, shot_draw=shot_draw)
            again = noise.apply_sensor_noise(moved, AMICA, seed, shot_draw=shot_draw)
            changed[shot_draw].append(np.mean(first != again))
    # A count moves with a probability about its shift in electrons (under 0.03), a code with a seventh of that.
    assert max(changed["inverse_cdf"]) < 1e-3
    assert max(changed["sampler"]) > 0.1


def _simulated_draws(rng, n_draws, scale):
    """Per-draw rows as noise_monte_carlo writes them, for an estimator whose light error is ``scale`` times the bound's."""
    cov = np.array([[1.0, 0.0], [0.0, 0.01]])  # one dominant direction, as at light 0
    delta = scale * rng.multivariate_normal([0, 0], cov, size=n_draws)
    std = np.sqrt(np.trace(cov))
    return pd.DataFrame({
        "set_id": "s", "noise_level": "amica12",
        "light_dir_err_deg": np.linalg.norm(delta, axis=1), "light_std_deg_bound": std,
        "light_err_sigma": np.linalg.norm(delta, axis=1) / std,
        "light_mahalanobis": np.sqrt(np.einsum("ni,ij,nj->n", delta, np.linalg.inv(cov), delta)),
        "efficiency_albedo": 1.0 / scale**2, "efficiency_k": 1.0 / scale**2,
    })


@pytest.mark.parametrize("scale", [1.0, 2.0])
def test_monte_carlo_summary_measures_the_excess_over_the_bound(scale):
    from asteroid_photometry.evaluation.metrics import monte_carlo_summary

    table = monte_carlo_summary(_simulated_draws(np.random.default_rng(3), 4000, scale)).set_index("set_id")
    row = table.loc["s"]
    assert row.draws == 4000
    assert row.light_rms_over_bound == pytest.approx(scale, rel=0.05)
    assert row.light_mahalanobis2_mean == pytest.approx(2 * scale**2, rel=0.08)
    expected_within = 0.95 if scale == 1.0 else 0.68  # |N(0, 1)| <= 2 and <= 1
    assert row.light_within_2sigma == pytest.approx(expected_within, abs=0.02)
    assert row.efficiency_albedo == pytest.approx(1 / scale**2)
    assert table.loc["all"].draws == 4000 and np.isnan(table.loc["all"].light_std_deg_bound)
