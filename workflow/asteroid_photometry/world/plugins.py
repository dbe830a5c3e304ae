"""Every photometric model as one Mitsuba BSDF plugin, ``photometric``.

The plugin is the same mechanism as ``render``'s Minnaert BSDF (a Python
``mi.BSDF`` subclass registered with the variant, traced into the JIT
kernel), generalised: its ``model`` property names a law of
``photometry.MODELS`` and the law's parameters ride along as properties.
The BSDF evaluates ``photometry``'s own formula with Dr.Jit operations,
``f_r cos_i = b / pi`` (directional Sun of irradiance pi, as in ``render``),
so a rendered pixel on a pure facet holds exactly the law's radiance factor.

Scene dictionary: ``{"type": "photometric", "model": "hapke", "w": 0.57,
...}`` (``bsdf_dict``). Uniform parameters only: the model-mismatch
experiment renders uniform surfaces.
"""

from __future__ import annotations

import numpy as np

from asteroid_photometry.reflectance import laws as photometry
from asteroid_photometry.world import render

PLUGIN_NAME = "photometric"


def bsdf_dict(model: str, params: dict) -> dict:
    """The Mitsuba scene entry of ``model`` with ``params`` (checked against the model's ranges)."""
    law = photometry.get_model(model)
    checked = law.check(params)
    entry = {"type": PLUGIN_NAME, "model": model}
    for name, value in checked.items():
        if np.ndim(value):
            raise ValueError(f"photometric model {model!r}: the renderer takes one value of {name!r} for the whole body")
        entry[name] = bool(value) if name in law.options else float(value)
    return entry


def register_photometric_plugin():
    """Define the photometric BSDF for the current Mitsuba variant and register it; returns the class."""
    import drjit as dr
    import mitsuba as mi

    ops = photometry.drjit_ops()

    class PhotometricBSDF(render.one_sided_diffuse_bsdf()):
        """``f_r = b(cos_i, cos_o, cos_g) / (pi cos_i)`` of one law of ``photometry``; one-sided."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.law = photometry.get_model(str(props.get("model", "lambert")))
            params = {}
            for name in self.law.parameters:
                if name not in props:
                    raise ValueError(f"photometric BSDF {self.law.name!r}: property {name!r} is missing")
                params[name] = float(props[name])
            for name in self.law.options:
                if name in props:
                    params[name] = bool(props[name])
            self.params = self.law.check(params)
            flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags

        def _value_times_cos(self, si, wo, active):
            # si.wi points to the camera, wo to the light, both in the local frame.
            cos_o = mi.Frame3f.cos_theta(si.wi)
            cos_i = mi.Frame3f.cos_theta(wo)
            cos_g = dr.dot(si.wi, wo)
            # 1 - cos g from the chord between the two directions: exact for small phase angles in float32.
            one_minus_cos_g = 0.5 * dr.squared_norm(si.wi - wo)
            # The azimuth between the planes of incidence and emission from the components in the
            # surface plane: accurate in float32 also near opposition, where the arccos of
            # (cos g - cos_i cos_o) / (sin_i sin_o) loses half the digits.
            psi = dr.atan2(dr.abs(si.wi.x * wo.y - si.wi.y * wo.x), si.wi.x * wo.x + si.wi.y * wo.y)
            valid = active & (cos_o > 0.0) & (cos_i > 0.0)
            value = self.law.radiance_factor(self.params, cos_i, cos_o, cos_g, ops, one_minus_cos_g, psi) * dr.inv_pi
            return dr.select(valid, value, 0.0)

        def to_string(self):
            return f"PhotometricBSDF[{self.law.name}, {self.params}]"

    mi.register_bsdf(PLUGIN_NAME, lambda props: PhotometricBSDF(props))
    return PhotometricBSDF


def render_sphere(radius_m, distance_m, image_size, fov_deg, bsdf: dict, light_dir_cam, spp, pixel_sampling="area") -> np.ndarray:
    """A sphere with ``bsdf`` (a ``bsdf_dict``) centred on the optical axis, for the closed-form checks.

    ``pixel_sampling``: ``render.PIXEL_SAMPLINGS`` (``centre`` with ``spp`` 1).
    """
    import mitsuba as mi
    from asteroid_photometry.world.cameras import ImagingGeometry, Intrinsics
    from asteroid_photometry.world.render import scene_dict

    focal_px = 0.5 * image_size / np.tan(np.radians(fov_deg) / 2)
    pose = np.eye(4)
    pose[2, 3] = distance_m
    geometry = ImagingGeometry(Intrinsics(image_size, image_size, focal_px, image_size / 2, image_size / 2), pose[None], distance_m, 0.0)
    body = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": radius_m, "bsdf": bsdf}
    scene = mi.load_dict(scene_dict(geometry, light_dir_cam, spp, body, pixel_sampling))
    return np.array(mi.render(scene, spp=spp), dtype=np.float64)[..., 0]


def bsdf_values(bsdf: dict, wi_local: np.ndarray, wo_local: np.ndarray):
    """The plugin's ``eval`` (``f_r cos_i``), ``pdf`` and ``sample`` weights at local directions, for the checks.

    ``wi_local`` (towards the camera) and ``wo_local`` (towards the light)
    are (n, 3) unit vectors in the surface's local frame (+z the normal).
    Returns ``(eval (n,), pdf (n,))``.
    """
    import mitsuba as mi

    plugin = mi.load_dict(bsdf)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*(np.ascontiguousarray(wi_local[:, j], dtype=np.float32) for j in range(3)))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    wo = mi.Vector3f(*(np.ascontiguousarray(wo_local[:, j], dtype=np.float32) for j in range(3)))
    ctx = mi.BSDFContext()
    value = np.array(plugin.eval(ctx, si, wo, True), dtype=np.float64)
    pdf = np.array(plugin.pdf(ctx, si, wo, True), dtype=np.float64)
    return (value[0] if value.ndim == 2 and value.shape[0] == 3 else value[..., 0]), pdf


def albedo_by_sampling(bsdf: dict, cos_incidence: float, n_samples: int = 200_000, seed: int = 0) -> float:
    """Directional-hemispherical albedo from the plugin's own ``sample`` (mean weight): the energy check.

    The light arrives from ``cos_incidence``; by reciprocity of the BRDF the
    albedo for light from there equals the mean of ``sample``'s weight with
    ``wi`` there.
    """
    import mitsuba as mi

    plugin = mi.load_dict(bsdf)
    rng = np.random.default_rng(seed)
    si = mi.SurfaceInteraction3f()
    sin_incidence = np.sqrt(1.0 - cos_incidence**2)
    si.wi = mi.Vector3f(float(sin_incidence), 0.0, float(cos_incidence))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    ctx = mi.BSDFContext()
    u = rng.uniform(size=(2, n_samples)).astype(np.float32)
    _, weight = plugin.sample(ctx, si, mi.Float(u[0]), mi.Point2f(mi.Float(u[0]), mi.Float(u[1])), True)
    weight = np.array(weight, dtype=np.float64)
    weight = weight[0] if weight.shape[0] == 3 else weight[..., 0]
    return float(weight.mean())
