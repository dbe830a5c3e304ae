"""The photometric model family: Lambert, Lommel-Seeliger, Lunar-Lambert, Minnaert and Hapke.

One formula per model serves both the renderer and the estimators: each
model's ``radiance_factor`` is written once against a small table of array
operations (``NUMPY_OPS`` here, ``drjit_ops()`` inside the Mitsuba plugin of
``render_models``), so the surface that is rendered and the law that is
fitted cannot drift apart.

Every model gives the radiance factor ``b`` (I/F; the package's brightness,
the radiance under a directional Sun of irradiance pi) of a surface element
as a function of ``cos_i`` (towards the Sun), ``cos_o`` (towards the camera)
and ``cos_g`` (the phase angle g between those two directions) and its
parameters; the BRDF is ``b / (pi cos_i)``.

- ``lambert``:          ``b = albedo cos_i``
- ``lommel_seeliger``:  ``b = albedo 2 cos_i / (cos_i + cos_o)`` (scaled so
  that ``albedo`` is the brightness at normal incidence and emission, as for
  the others)
- ``lunar_lambert``:    McEwen's blend, ``b = albedo [2 L cos_i / (cos_i +
  cos_o) + (1 - L) cos_i]``: Lambert at L = 0, Lommel-Seeliger at L = 1
- ``minnaert``:         ``b = albedo cos_i^k cos_o^(k - 1)`` (the package's
  law, :func:`minnaert_brightness`)
- ``hapke``:            see :func:`hapke_radiance_factor`.

Parameters are plain dicts of scalars or arrays that broadcast against the
cosines. ``PhotometricModel.jacobian`` differentiates any model by central
differences, with respect to its parameters and to ``cos_i`` and ``cos_g``
(the light enters through those two): the fits need nothing more.
"""

from __future__ import annotations

import dataclasses
import math
import types

import numpy as np

__all__ = ["PhotometricModel", "MODELS", "get_model", "minnaert_brightness", "minnaert_factor", "NUMPY_OPS", "drjit_ops", "hapke_radiance_factor", "geometry_cosines"]

# Cosines are floored here inside the laws: grazing rows never reach the fits
# (observe keeps cos >= 0.1), the floor only keeps logs and divisions finite.
COS_FLOOR = 1e-6

NUMPY_OPS = types.SimpleNamespace(
    sqrt=np.sqrt, exp=np.exp, log=np.log, power=np.power, tan=np.tan, cos=np.cos, sin=np.sin, arccos=np.arccos,
    maximum=np.maximum, minimum=np.minimum, where=np.where,
)


def drjit_ops():
    """The same operations on Dr.Jit arrays (for the Mitsuba plugin; needs a variant set)."""
    import drjit as dr

    return types.SimpleNamespace(
        sqrt=dr.sqrt, exp=dr.exp, log=dr.log, power=dr.power, tan=dr.tan, cos=dr.cos, sin=dr.sin, arccos=dr.acos,
        maximum=dr.maximum, minimum=dr.minimum, where=dr.select,
    )


def _clip(ops, x, low, high):
    return ops.minimum(ops.maximum(x, low), high)


def geometry_cosines(normal, light, view):
    """``(cos_i, cos_o, cos_g)`` of unit normals, light and view directions (arrays (..., 3), broadcast)."""
    normal, light, view = (np.asarray(v, dtype=np.float64) for v in (normal, light, view))
    return np.sum(normal * light, axis=-1), np.sum(normal * view, axis=-1), np.sum(light * view, axis=-1)


# --------------------------------------------------------------------------
# The laws
# --------------------------------------------------------------------------


def _lambert(p, cos_i, cos_o, cos_g, ops, one_minus_cos_g=None, psi=None):
    return p["albedo"] * cos_i


def _lommel_seeliger(p, cos_i, cos_o, cos_g, ops, one_minus_cos_g=None, psi=None):
    return p["albedo"] * 2.0 * cos_i / (cos_i + cos_o)


def _lunar_lambert(p, cos_i, cos_o, cos_g, ops, one_minus_cos_g=None, psi=None):
    lunar_l = p["lunar_l"]
    return p["albedo"] * (2.0 * lunar_l * cos_i / (cos_i + cos_o) + (1.0 - lunar_l) * cos_i)


def _minnaert(p, cos_i, cos_o, cos_g, ops, one_minus_cos_g=None, psi=None):
    # The log form (minnaert_factor), not minnaert_brightness's powers: the two differ in the last bits.
    return p["albedo"] * minnaert_factor(p["minnaert_k"], ops.log(cos_i), ops.log(cos_o), ops)


def _henyey_greenstein(cos_g, asymmetry, ops):
    """One Henyey-Greenstein lobe in the phase angle; ``asymmetry`` > 0 scatters back towards the Sun."""
    denominator = 1.0 - 2.0 * asymmetry * cos_g + asymmetry * asymmetry
    return (1.0 - asymmetry * asymmetry) / (denominator * ops.sqrt(denominator))


def _chandrasekhar_h(x, w, ops):
    """Hapke's (2002, eq. 13) approximation of Chandrasekhar's H function for isotropic scatterers."""
    gamma = ops.sqrt(1.0 - w)
    r0 = (1.0 - gamma) / (1.0 + gamma)
    return 1.0 / (1.0 - w * x * (r0 + (1.0 - 2.0 * r0 * x) * 0.5 * ops.log((1.0 + x) / x)))


def hapke_radiance_factor(p, cos_i, cos_o, cos_g, ops=NUMPY_OPS, multiple_scattering=True, one_minus_cos_g=None, psi=None):
    """Hapke's radiance factor with shadow-hiding opposition and macroscopic roughness.

    The formulation is the one of Hapke's 1993 book (Theory of Reflectance
    and Emittance Spectroscopy, ch. 8 and 12) with the improved H function of
    Hapke (2002, Icarus 157, 523): the isotropic-multiple-scattering
    approximation (IMSA), ``r = w / (4 pi) mu0e / (mu0e + mue) [(1 + B(g))
    p(g) + H(mu0e) H(mue) - 1] S(i, e, g)``, returned as ``b = pi r``.

    - ``w``: single-scattering albedo.
    - ``p(g)``: the two-term Henyey-Greenstein phase function in Hapke's
      (2012) form, ``(1 + c) / 2 HG(b) + (1 - c) / 2 HG(-b)`` with ``HG(b)``
      the lobe that peaks at g = 0 for b > 0 (``hg_b`` the lobe width,
      ``hg_c`` the partition; ``hg_c = 1`` is a one-term backscattering
      lobe, ``hg_b = 0`` is isotropic).
    - ``B(g) = b0 / (1 + tan(g / 2) / h)``: the shadow-hiding opposition
      surge (amplitude ``b0``, angular width ``h``).
    - ``S``, ``mu0e``, ``mue``: macroscopic roughness of mean slope
      ``roughness_deg`` (Hapke 1984, Icarus 59, 41), the two cases i <= e and
      e < i written as one expression with a select. The shadowing in the
      reciprocal form (the effective ``mue`` in S), so the BRDF is symmetric.

    ``multiple_scattering=False`` drops the ``H H - 1`` term (the
    single-scattering limit); with roughness 0, ``hg_b`` 0 and ``b0`` 0 the
    law is then ``w / 8`` times Lommel-Seeliger's.

    ``one_minus_cos_g``, where given, is ``1 - cos g`` computed without
    cancellation (the renderer's float32 cos g near 1 resolves g only to
    0.02 deg, too coarse for the opposition surge at phase 0).

    ``psi``, where given, is the azimuth between the planes of incidence and
    emission (radians, in [0, pi]) measured directly (the renderer's, from
    the directions' components in the surface plane). Without it psi is
    ``arccos((cos g - cos_i cos_o) / (sin_i sin_e))``: exact in float64,
    but in float32 near opposition (psi small) the cosine's rounding, about
    1e-7, becomes an error of sqrt(2e-7), about 5e-4 rad, in psi, and the
    roughness correction, steep in psi there, moves by up to 1e-3 relative.
    """
    w, b0, h = p["w"], p["b0"], p["h"]
    mu0 = ops.maximum(cos_i, COS_FLOOR)
    mu = ops.maximum(cos_o, COS_FLOOR)
    cos_g = _clip(ops, cos_g, -1.0, 1.0)
    # tan(g/2) = sqrt((1 - cos g) / (1 + cos g)).
    versine = (1.0 - cos_g) if one_minus_cos_g is None else ops.maximum(one_minus_cos_g, 0.0)
    tan_half_g = ops.sqrt(versine / ops.maximum(2.0 - versine, COS_FLOOR))
    opposition = b0 / (1.0 + tan_half_g / h)
    hg_b, hg_c = p["hg_b"], p["hg_c"]
    phase = 0.5 * (1.0 + hg_c) * _henyey_greenstein(cos_g, hg_b, ops) + 0.5 * (1.0 - hg_c) * _henyey_greenstein(cos_g, -hg_b, ops)

    # Macroscopic roughness (Hapke 1984). A floor on tan(theta-bar) makes the
    # smooth surface the limit of the same expressions (chi -> 1, S -> 1).
    tan_theta = ops.maximum(ops.tan(p["roughness_deg"] * (math.pi / 180.0)), 1e-6)
    cot_theta = 1.0 / tan_theta
    chi = 1.0 / ops.sqrt(1.0 + math.pi * tan_theta * tan_theta)
    sin_i = ops.sqrt(ops.maximum(1.0 - mu0 * mu0, COS_FLOOR * COS_FLOOR))
    sin_e = ops.sqrt(ops.maximum(1.0 - mu * mu, COS_FLOOR * COS_FLOOR))
    cot_i, cot_e = mu0 / sin_i, mu / sin_e
    e1_i = ops.exp(-2.0 / math.pi * cot_theta * cot_i)
    e1_e = ops.exp(-2.0 / math.pi * cot_theta * cot_e)
    e2_i = ops.exp(-1.0 / math.pi * cot_theta * cot_theta * cot_i * cot_i)
    e2_e = ops.exp(-1.0 / math.pi * cot_theta * cot_theta * cot_e * cot_e)
    # psi: the azimuth between the planes of incidence and emission.
    if psi is None:
        cos_psi = _clip(ops, (cos_g - mu0 * mu) / (sin_i * sin_e), -1.0, 1.0)
        psi = ops.arccos(cos_psi)
        sin2_half_psi = 0.5 * (1.0 - cos_psi)
    else:
        psi = _clip(ops, psi, 0.0, math.pi)
        cos_psi = ops.cos(psi)
        sin_half_psi = ops.sin(0.5 * psi)
        sin2_half_psi = sin_half_psi * sin_half_psi
    f_psi = ops.exp(-2.0 * ops.tan(ops.minimum(psi, math.pi - 1e-3) * 0.5))
    eta_i = chi * (mu0 + sin_i * tan_theta * e2_i / (2.0 - e1_i))
    eta_e = chi * (mu + sin_e * tan_theta * e2_e / (2.0 - e1_e))
    i_first = mu0 >= mu  # i <= e
    # Case i <= e.
    den_1 = 2.0 - e1_e - psi / math.pi * e1_i
    mu0e_1 = chi * (mu0 + sin_i * tan_theta * (cos_psi * e2_e + sin2_half_psi * e2_i) / den_1)
    mue_1 = chi * (mu + sin_e * tan_theta * (e2_e - sin2_half_psi * e2_i) / den_1)
    # Case e < i.
    den_2 = 2.0 - e1_i - psi / math.pi * e1_e
    mu0e_2 = chi * (mu0 + sin_i * tan_theta * (e2_i - sin2_half_psi * e2_e) / den_2)
    mue_2 = chi * (mu + sin_e * tan_theta * (cos_psi * e2_i + sin2_half_psi * e2_e) / den_2)
    mu0e = ops.where(i_first, mu0e_1, mu0e_2)
    mue = ops.where(i_first, mue_1, mue_2)
    shadow_ratio = ops.where(i_first, mu0 / eta_i, mu / eta_e)
    shadowing = (mue / eta_e) * (mu0 / eta_i) * chi / (1.0 - f_psi + f_psi * chi * shadow_ratio)

    mu0e = ops.maximum(mu0e, COS_FLOOR)
    mue = ops.maximum(mue, COS_FLOOR)
    scattering = (1.0 + opposition) * phase
    if multiple_scattering:
        scattering = scattering + _chandrasekhar_h(mu0e, w, ops) * _chandrasekhar_h(mue, w, ops) - 1.0
    return 0.25 * w * mu0e / (mu0e + mue) * scattering * shadowing


def _hapke(p, cos_i, cos_o, cos_g, ops, one_minus_cos_g=None, psi=None):
    return hapke_radiance_factor(p, cos_i, cos_o, cos_g, ops, multiple_scattering=bool(p.get("multiple_scattering", True)), one_minus_cos_g=one_minus_cos_g, psi=psi)


# --------------------------------------------------------------------------
# The interface
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PhotometricModel:
    """One law: its name, parameter names (the first scales the brightness), valid ranges and formula.

    ``options`` are settings that are not fitted (Hapke's ``multiple_scattering``).
    """

    name: str
    parameters: tuple
    ranges: dict
    law: object
    options: tuple = ()

    def check(self, params: dict) -> dict:
        """``params`` with floats, or a ValueError naming the missing, unknown or out-of-range parameter."""
        missing = [name for name in self.parameters if name not in params]
        unknown = [name for name in params if name not in self.parameters and name not in self.options]
        if missing or unknown:
            raise ValueError(
                f"photometric model {self.name!r}: parameters {self.parameters} expected"
                + (f"; missing {missing}" if missing else "") + (f"; unknown {unknown}" if unknown else "")
            )
        checked = dict(params)
        for name in self.parameters:
            value = np.asarray(params[name], dtype=np.float64)
            low, high = self.ranges[name]
            if not np.all(np.isfinite(value)) or np.any(value < low) or np.any(value > high):
                raise ValueError(f"photometric model {self.name!r}: parameter {name!r} must lie in [{low}, {high}], got {params[name]}")
            checked[name] = value if value.ndim else float(value)
        return checked

    def radiance_factor(self, params: dict, cos_i, cos_o, cos_g, ops=NUMPY_OPS, one_minus_cos_g=None, psi=None):
        """``b`` for every row (numpy arrays broadcast; Dr.Jit arrays with ``ops=drjit_ops()``).

        ``one_minus_cos_g``: optional, ``1 - cos_g`` free of cancellation (the renderer's).
        ``psi``: optional, the azimuth between the planes of incidence and
        emission measured directly (the renderer's; only Hapke uses it).
        """
        if ops is NUMPY_OPS:
            cos_i = np.maximum(np.asarray(cos_i, dtype=np.float64), COS_FLOOR)
            cos_o = np.maximum(np.asarray(cos_o, dtype=np.float64), COS_FLOOR)
            cos_g = np.asarray(cos_g, dtype=np.float64)
        else:
            cos_i, cos_o = ops.maximum(cos_i, COS_FLOOR), ops.maximum(cos_o, COS_FLOOR)
        return self.law(params, cos_i, cos_o, cos_g, ops, one_minus_cos_g, psi)

    def jacobian(self, params: dict, cos_i, cos_o, cos_g, names, step=1e-6, central=True):
        """Finite-difference derivatives of ``b`` with respect to ``names``.

        ``names`` may hold parameter names and ``"cos_i"`` / ``"cos_g"``;
        returns ``(b, {name: db/dname})``. Forward differences (one law
        evaluation per name, about 1e-7 relative error, plenty for
        Gauss-Newton) or ``central`` ones (two, about 1e-10). Steps are
        relative to the value (absolute near zero) and turn inwards at a
        parameter's bound.
        """
        base = self.radiance_factor(params, cos_i, cos_o, cos_g)
        variables = {**params, "cos_i": np.asarray(cos_i, dtype=np.float64), "cos_g": np.asarray(cos_g, dtype=np.float64)}
        bounds = {**self.ranges, "cos_i": (-1.0, 1.0), "cos_g": (-1.0, 1.0)}

        def evaluate(values):
            law_params = {name: value for name, value in values.items() if name not in ("cos_i", "cos_g")}
            return self.radiance_factor(law_params, values["cos_i"], cos_o, values["cos_g"])

        derivatives = {}
        for name in names:
            value = np.asarray(variables[name], dtype=np.float64)
            delta = step * np.maximum(np.abs(value), 1e-2 if name not in ("cos_i", "cos_g") else 1.0)
            low, high = bounds[name]
            if central:
                up, down = np.minimum(value + delta, high), np.maximum(value - delta, low)
                derivatives[name] = (evaluate({**variables, name: up}) - evaluate({**variables, name: down})) / (up - down)
            else:
                moved = np.where(value + delta <= high, value + delta, value - delta)
                derivatives[name] = (evaluate({**variables, name: moved}) - base) / (moved - value)
        return base, derivatives


_ALBEDO = (0.0, 10.0)
MODELS = {
    "lambert": PhotometricModel("lambert", ("albedo",), {"albedo": _ALBEDO}, _lambert),
    "lommel_seeliger": PhotometricModel("lommel_seeliger", ("albedo",), {"albedo": _ALBEDO}, _lommel_seeliger),
    "lunar_lambert": PhotometricModel("lunar_lambert", ("albedo", "lunar_l"), {"albedo": _ALBEDO, "lunar_l": (-1.0, 3.0)}, _lunar_lambert),
    "minnaert": PhotometricModel("minnaert", ("albedo", "minnaert_k"), {"albedo": _ALBEDO, "minnaert_k": (0.05, 3.0)}, _minnaert),
    "hapke": PhotometricModel(
        "hapke",
        ("w", "roughness_deg", "hg_b", "hg_c", "b0", "h"),
        {"w": (0.0, 0.999), "roughness_deg": (0.0, 60.0), "hg_b": (0.0, 0.95), "hg_c": (-1.0, 1.0), "b0": (0.0, 10.0), "h": (1e-4, 2.0)},
        _hapke,
        options=("multiple_scattering",),
    ),
}


def get_model(name: str) -> PhotometricModel:
    if name not in MODELS:
        raise ValueError(f"unknown photometric model {name!r} (known: {', '.join(MODELS)})")
    return MODELS[name]


def minnaert_factor(minnaert_k, log_cos_i, log_cos_o, ops=NUMPY_OPS):
    """``cos_i**k cos_o**(k - 1)`` from the cosines' logs: ``exp(k log cos_i + (k - 1) log cos_o)``.

    The log form of the Minnaert law, for callers that have the logs already
    (the model family's ``minnaert``, numpy or Dr.Jit ``ops``; the joint
    fit's residuals in ``estimation.koizumi``). Not bit-for-bit the same as
    the power form of :func:`minnaert_brightness`.
    """
    return ops.exp(minnaert_k * log_cos_i + (minnaert_k - 1.0) * log_cos_o)


def minnaert_brightness(albedo, minnaert_k, cos_incidence, cos_emission) -> np.ndarray:
    """``albedo * cos_i**k * cos_o**(k - 1)``, zero where ``cos_i <= 0`` (unlit).

    The package's Minnaert law on plain cosines (numpy powers); the log form
    is :func:`minnaert_factor`. The Mitsuba plugin of ``world.render`` writes
    the same law as its own Dr.Jit expression.
    """
    cos_i = np.asarray(cos_incidence, dtype=np.float64)
    lit = cos_i > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        value = albedo * np.power(np.where(lit, cos_i, 1.0), minnaert_k) * np.power(cos_emission, minnaert_k - 1.0)
    return np.where(lit, value, 0.0)
