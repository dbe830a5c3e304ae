"""Sensor noise: what a real camera would record of a rendered (noise-free) radiance image.

The render stage produces linear float images of the Minnaert radiance
``b`` (see ``render``). A CCD turns that radiance into a count of
photo-electrons, adds read noise and digitises the result; this module
models that chain so that the estimators can be run on noisy images and
their errors compared with the Cramer-Rao bound:

1. expected electrons ``mu = gain * b`` with ``gain = full_well_e /
   radiance_at_full_well`` (electrons per unit radiance; the exposure is
   fixed so that radiance ``radiance_at_full_well`` fills the well);
2. shot noise: ``e ~ Poisson(mu)``;
3. read noise: ``e += Normal(0, read_noise_e)``;
4. an ADC of ``bit_depth`` bits spanning 0 .. ``full_well_e``: ``DN =
   round(e / q_e)`` clipped to ``0 .. 2**bit_depth - 1``, with ``q_e =
   full_well_e / (2**bit_depth - 1)`` electrons per DN (top code = full well,
   so saturation is the clip);
5. back to radiance units: ``DN * q_e / gain``.

The returned value is thus an unbiased (away from the clips) estimate of
``b`` with variance ``b / gain + (read_noise_e / gain)**2 + q**2 / 12``, ``q =
radiance_at_full_well / (2**bit_depth - 1)`` the quantisation step in
radiance units (``observation_variance``). The quantisation term is the
usual uniform-error approximation; it is good to 1 % when the other noise
is at least 0.6 steps, as in every level below (read noise alone is over
1.5 steps), and fails for a nearly noiseless signal, whose rounding error
is then a fixed bias rather than noise.

Exposure. With ``radiance_at_full_well = 1`` (the default) the brightest
pixels of the rendered sets (``b`` about the albedo, at most 0.7 in the
default config) fill 70 % of the well: nothing saturates, and the exposure
is the same for every set, as for a real camera. With ``surface_maps``
the brightest facets reach albedo 1 (radiance up to about 1.01 on the
Gaskell model at albedo 0.7 with a 0.2 contrast): a few pixels hit the top
code. ``saturated`` finds them, to be dropped as a real pipeline would, or
set ``radiance_at_full_well: 1.25``.

Proposed sweep of ``noise_levels`` (``PROPOSED_NOISE_LEVELS``): one camera
per decade-ish step in noise, centred on Hayabusa's AMICA. AMICA digitises
to 12 bits and is linear below about 3800 DN (Ishiguro et al. 2010, Icarus
207, 714); the well depth and read noise below are representative of a
CCD with its 12 um pixels, not AMICA's calibrated values. Relative noise
``sqrt(var) / b`` at a typical lit pixel ``b = 0.35`` (and a dim one,
``b = 0.1``):

- ``low``, ``scientific_16bit``: full well 300,000 e-, read noise 7 e-,
  16 bits. A large-pixel scientific CCD, shot-noise limited: about the best
  one frame can do. 0.31 % (0.58 %).
- ``middle``, ``amica_12bit``: full well 30,000 e-, read noise 20 e-,
  12 bits (7.3 e-/DN). An AMICA-like camera exposed to use its range.
  0.99 % (1.9 %).
- ``high``, ``amica_12bit_underexposed``: the same camera with a 10 times
  shorter exposure (``radiance_at_full_well: 10``), the usual way real
  frames of a bright, fast-moving target get noisy: read noise now rivals
  shot noise and the signal spans under a tenth of the ADC codes. 3.6 % (8.8 %).

The steps are x3.2 and x3.6 in noise (x10 and x13 in variance), so the
sweep spans a decade around AMICA and the estimators' errors, which scale with the noise
when the fit is well conditioned, should fall on a straight line in a
log-log plot; a departure from it flags bias (clipping, a nonlinear
estimator at low SNR) rather than variance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from scipy.special import ndtri, pdtr

CONFIG_KEY = "noise_levels"

# The proposed sweep, in the config's format (see the module docstring for why).
PROPOSED_NOISE_LEVELS = (
    {"name": "scientific_16bit", "full_well_e": 300000, "read_noise_e": 7, "bit_depth": 16},
    {"name": "amica_12bit", "full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12},
    {"name": "amica_12bit_underexposed", "full_well_e": 30000, "read_noise_e": 20, "bit_depth": 12, "radiance_at_full_well": 10.0},
)

# Radiances beyond this many full wells are capped before the Poisson draw (they
# saturate anyway; the cap keeps numpy's Poisson sampler in range).
_SATURATION_CAP = 4.0


@dataclass(frozen=True)
class SensorModel:
    """A linear camera: its well depth, read noise and ADC, and the radiance that fills the well.

    ``name`` only labels error messages and logs.
    """

    full_well_e: float
    read_noise_e: float
    bit_depth: int
    radiance_at_full_well: float = 1.0
    name: str = ""

    def __post_init__(self):
        where = f"config key '{CONFIG_KEY}'" + (f", level {self.name!r}" if self.name else "")

        def number(field_name, value):
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
                raise ValueError(f"{where}: {field_name} must be a finite number, got {value!r}")
            return float(value)

        if number("full_well_e", self.full_well_e) <= 0:
            raise ValueError(f"{where}: full_well_e must be > 0 electrons, got {self.full_well_e!r}")
        if number("read_noise_e", self.read_noise_e) < 0:
            raise ValueError(f"{where}: read_noise_e must be >= 0 electrons, got {self.read_noise_e!r}")
        if number("radiance_at_full_well", self.radiance_at_full_well) <= 0:
            raise ValueError(f"{where}: radiance_at_full_well must be > 0, got {self.radiance_at_full_well!r}")
        bits = self.bit_depth
        if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)) or not 1 <= bits <= 32:
            raise ValueError(f"{where}: bit_depth must be an integer from 1 to 32, got {bits!r}")
        # Normalise types so that equal sensors compare and hash equal.
        object.__setattr__(self, "full_well_e", float(self.full_well_e))
        object.__setattr__(self, "read_noise_e", float(self.read_noise_e))
        object.__setattr__(self, "radiance_at_full_well", float(self.radiance_at_full_well))
        object.__setattr__(self, "bit_depth", int(bits))

    @property
    def gain_e_per_radiance(self) -> float:
        """Expected electrons per unit of linear radiance."""
        return self.full_well_e / self.radiance_at_full_well

    @property
    def max_code(self) -> int:
        """The ADC's top code, ``2**bit_depth - 1``: it stands for the full well."""
        return 2**self.bit_depth - 1

    @property
    def electrons_per_dn(self) -> float:
        return self.full_well_e / self.max_code

    @property
    def quantisation_step(self) -> float:
        """One ADC step in radiance units."""
        return self.radiance_at_full_well / self.max_code

    def to_dict(self) -> dict:
        """The config entry of this sensor (the inverse of ``sensor_from_config``)."""
        entry = {field.name: getattr(self, field.name) for field in fields(self)}
        if not entry["name"]:
            del entry["name"]
        return entry


def sensor_from_config(level: dict) -> SensorModel:
    """A ``SensorModel`` from one entry of the config's ``noise_levels`` list.

    Keys: ``full_well_e``, ``read_noise_e``, ``bit_depth`` (required),
    ``radiance_at_full_well`` (default 1.0) and ``name`` (a label). Unknown or
    missing keys raise a ValueError that names them.
    """
    if not isinstance(level, dict):
        raise ValueError(f"config key '{CONFIG_KEY}': each level must be a mapping, got {level!r}")
    name = str(level.get("name", ""))
    where = f"config key '{CONFIG_KEY}'" + (f", level {name!r}" if name else "")
    allowed = {field.name for field in fields(SensorModel)}
    unknown = sorted(set(level) - allowed)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    missing = [key for key in ("full_well_e", "read_noise_e", "bit_depth") if key not in level]
    if missing:
        raise ValueError(f"{where}: missing key(s) {missing}")
    bit_depth = level["bit_depth"]
    if isinstance(bit_depth, float) and bit_depth.is_integer():
        bit_depth = int(bit_depth)  # YAML or JSON may give 12.0
    return SensorModel(
        full_well_e=level["full_well_e"],
        read_noise_e=level["read_noise_e"],
        bit_depth=bit_depth,
        radiance_at_full_well=level.get("radiance_at_full_well", 1.0),
        name=name,
    )


#: Steps of ``poisson_quantile``'s correction after its start; none past 4 was needed on 10 to 3,000 electrons.
_QUANTILE_MAX_STEPS = 64

#: How ``apply_sensor_noise`` can draw the shot noise (its ``shot_draw``).
SHOT_DRAWS = ("sampler", "inverse_cdf")


def poisson_quantile(expected, uniforms) -> np.ndarray:
    """The Poisson law's quantile of ``uniforms`` (in [0, 1)) at means ``expected`` (>= 0), elementwise, as float64.

    The smallest count ``k`` whose CDF (``scipy.special.pdtr``) reaches the
    uniform: a Poisson draw when the uniform is uniform, the same counts as
    ``scipy.stats.poisson.ppf``. Each count is a function of its own mean and
    uniform alone. It starts from the Cornish-Fisher quantile, ``lam + sqrt(lam)
    z + (z**2 - 1) / 6`` with ``z`` the normal quantile of the uniform, and
    steps up or down while the CDF says so (about one step a count), only
    where the step is still to be taken. A zero mean gives zero.
    """
    lam = np.asarray(expected, dtype=np.float64)
    u = np.asarray(uniforms, dtype=np.float64)
    if lam.shape != u.shape:
        raise ValueError(f"poisson_quantile: {lam.shape} means but {u.shape} uniforms")
    counts = np.zeros(lam.shape)
    lit = np.flatnonzero(lam > 0.0)
    lam, u = lam.ravel()[lit], u.ravel()[lit]
    z = ndtri(np.clip(u, 1e-300, 1.0 - 1e-16))
    k = np.maximum(np.floor(lam + np.sqrt(lam) * z + (z * z - 1.0) / 6.0), 0.0)
    open_ = np.arange(lam.size)  # the counts that may still move
    for _ in range(_QUANTILE_MAX_STEPS):
        k_open, lam_open, u_open = k[open_], lam[open_], u[open_]
        up = pdtr(k_open, lam_open) < u_open  # the CDF at k is still below the uniform: the count is higher
        lower = ~up & (k_open > 0.0)
        down = np.zeros_like(up)
        down[lower] = pdtr(k_open[lower] - 1.0, lam_open[lower]) >= u_open[lower]  # one below already reaches it
        moved = up | down
        if not moved.any():
            counts.flat[lit] = k
            return counts
        k[open_] = k_open + up - down
        open_ = open_[moved]
    raise RuntimeError(f"poisson_quantile: the count did not settle within {_QUANTILE_MAX_STEPS} steps")


def apply_sensor_noise(image: np.ndarray, sensor: SensorModel, rng, shot_draw: str = "sampler") -> np.ndarray:
    """A noisy, digitised copy of the linear radiance ``image`` (any shape), in radiance units.

    ``rng`` is a ``numpy.random.Generator`` (or a seed for one); the result is
    a deterministic function of ``image``, ``sensor`` and the generator's
    state. Negative radiance (none in a rendering) counts as zero light. Returns float64.

    ``shot_draw`` says how the shot noise is drawn (``SHOT_DRAWS``):

    - ``"sampler"``: numpy's Poisson sampler, the fastest. It takes a number
      of the generator's values that depends on each expected count, so a
      change in one pixel's last digits can put every later pixel's noise out
      of step: a render that differs in its last bits (another processor's
      vector width) can give another draw of the rest of the image.
    - ``"inverse_cdf"``: one uniform a pixel, turned into a count by
      ``poisson_quantile``. Each count follows its own pixel alone and moves
      by one electron, with a probability about the shift of its expected
      count in electrons, when that moves: such a render keeps nearly all
      its counts. About four times as long as the sampler (bench/bench_shot_noise.py).

    Both take the read noise after the shot noise, one normal a pixel.
    """
    if shot_draw not in SHOT_DRAWS:
        raise ValueError(f"apply_sensor_noise: shot_draw must be one of {SHOT_DRAWS}, got {shot_draw!r}")
    rng = np.random.default_rng(rng)
    radiance = np.asarray(image, dtype=np.float64)
    if not np.all(np.isfinite(radiance)):
        raise ValueError("apply_sensor_noise: the image has NaN or infinite pixels")
    gain = sensor.gain_e_per_radiance
    expected_e = np.clip(radiance, 0.0, _SATURATION_CAP * sensor.radiance_at_full_well) * gain
    if shot_draw == "sampler":
        electrons = rng.poisson(expected_e).astype(np.float64)
    else:
        electrons = poisson_quantile(expected_e, rng.random(expected_e.shape))
    if sensor.read_noise_e > 0:
        electrons += rng.normal(0.0, sensor.read_noise_e, size=electrons.shape)
    codes = np.clip(np.rint(electrons / sensor.electrons_per_dn), 0, sensor.max_code)
    return codes * (sensor.electrons_per_dn / gain)


def observation_variance(brightness, sensor: SensorModel):
    """Variance of ``apply_sensor_noise``'s value for true radiance ``brightness``, in radiance^2.

    ``brightness / gain`` (shot) ``+ (read_noise_e / gain)**2 + q**2 / 12``
    (quantisation, ``q`` one ADC step): the per-observation variance for a
    Fisher information / Cramer-Rao computation. Valid away from the clips
    (``0 < brightness < radiance_at_full_well`` by a few standard
    deviations). Vectorised over ``brightness``.
    """
    brightness = np.asarray(brightness, dtype=np.float64)
    gain = sensor.gain_e_per_radiance
    return np.clip(brightness, 0.0, None) / gain + (sensor.read_noise_e / gain) ** 2 + sensor.quantisation_step**2 / 12.0


def saturated(values, sensor: SensorModel) -> np.ndarray:
    """Where ``apply_sensor_noise``'s output sits at the ADC's top code: the true value is unknown there."""
    return np.asarray(values) >= sensor.max_code * sensor.electrons_per_dn / sensor.gain_e_per_radiance


#: A zero signal reads above ``DARK_SIGMA`` standard deviations of its own noise with probability under 3e-7.
DARK_SIGMA = 5.0


def dark_level(sensor: SensorModel, n_sigma: float = DARK_SIGMA) -> float:
    """The radiance a dark pixel (no light) stays below but for one in millions: ``n_sigma`` times its noise.

    A zero signal has no shot noise: read noise and quantisation only,
    ``sqrt((read_noise_e / gain)**2 + q**2 / 12)``.
    """
    return float(n_sigma * np.sqrt(observation_variance(0.0, sensor)))
