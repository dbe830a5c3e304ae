"""The photometric Mitsuba plugin against the laws: sphere images, the Hapke limit, reciprocity, energy."""

import numpy as np
import pytest
from scipy.ndimage import binary_dilation
from test_photometry import PARAMS

from asteroid_photometry.reflectance import laws as photometry
from asteroid_photometry.world import cameras, plugins as render_models, render
from synthetic_helpers import sphere_image_closed_form

SPHERE = dict(radius_m=100.0, distance_m=5000.0, image_size=48, fov_deg=2.6)
SPP = 64


@pytest.fixture(scope="module")
def variant():
    return render.setup_mitsuba("auto")


def closed_form_sphere(model, params, light, radius_m, distance_m, image_size, fov_deg, supersample=6):
    """Pixel means and spreads of the law's sphere image (``synthetic_helpers.sphere_image_closed_form``)."""
    law = photometry.get_model(model)
    return sphere_image_closed_form(
        lambda cos_i, cos_o, cos_g: law.radiance_factor(params, cos_i, cos_o, cos_g), light, radius_m, distance_m, image_size, fov_deg, supersample
    )


@pytest.mark.parametrize("model", list(photometry.MODELS))
def test_sphere_image_matches_the_law(variant, model):
    light = cameras.light_dir_cam(25.0)
    image = render_models.render_sphere(**SPHERE, bsdf=render_models.bsdf_dict(model, PARAMS[model]), light_dir_cam=light, spp=SPP)
    expected, spread, interior = closed_form_sphere(model, PARAMS[model], light, **SPHERE)
    assert interior.sum() > 400
    difference = np.abs(image - expected)[interior]
    z = difference / (spread[interior] / np.sqrt(SPP) + 2e-7)
    assert np.mean(z) < 1.2 and np.percentile(z, 99.9) < 6
    near_lit = binary_dilation(expected > 0, iterations=2)
    assert np.all(image[~near_lit] == 0)
    # The check can fail: the image of another law is far off.
    other = "minnaert" if model != "minnaert" else "lambert"
    wrong, _, _ = closed_form_sphere(other, PARAMS[other], light, **SPHERE)
    assert np.abs(image - wrong)[interior].mean() > 10 * difference.mean()


def test_centre_sampling_renders_the_law_at_the_pixel_centre_ray_at_opposition(variant):
    """One ray through each pixel's centre: the Hapke sphere at phase 0 is the law on those rays to float32 rounding.

    Random rays average the radiance over the pixel instead (here over the
    sphere's curvature as well), which the check tells apart.
    """
    light = cameras.light_dir_cam(0.0)
    bsdf = render_models.bsdf_dict("hapke", PARAMS["hapke"])
    centre_ray, _, interior = closed_form_sphere("hapke", PARAMS["hapke"], light, **SPHERE, supersample=1)
    assert interior.sum() > 400
    centre_ray = centre_ray[interior]
    centred = render_models.render_sphere(**SPHERE, bsdf=bsdf, light_dir_cam=light, spp=1, pixel_sampling="centre")[interior]
    error = np.abs(centred / centre_ray - 1.0)
    assert np.max(error) < 2e-6
    area = render_models.render_sphere(**SPHERE, bsdf=bsdf, light_dir_cam=light, spp=4)[interior]
    assert np.sqrt(np.mean((area / centre_ray - 1.0) ** 2)) > 10 * np.sqrt(np.mean(error**2))
    with pytest.raises(ValueError, match="one ray per pixel"):
        render_models.render_sphere(**SPHERE, bsdf=bsdf, light_dir_cam=light, spp=4, pixel_sampling="centre")


def test_hapke_plugin_limit_renders_the_lommel_seeliger_image(variant):
    light = cameras.light_dir_cam(25.0)
    limit = dict(w=0.57, roughness_deg=0.0, hg_b=0.0, hg_c=1.0, b0=0.0, h=0.05, multiple_scattering=False)
    hapke = render_models.render_sphere(**SPHERE, bsdf=render_models.bsdf_dict("hapke", limit), light_dir_cam=light, spp=SPP)
    lommel = render_models.render_sphere(**SPHERE, bsdf=render_models.bsdf_dict("lommel_seeliger", {"albedo": 0.57 / 8}), light_dir_cam=light, spp=SPP)
    assert lommel.max() > 0.05
    assert np.max(np.abs(hapke - lommel)) < 1e-6  # the same samples; float32 arithmetic


def hemisphere(n, rng):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("model", list(photometry.MODELS))
def test_plugin_is_reciprocal_and_evaluates_the_law(variant, model):
    rng = np.random.default_rng(4)
    wi, wo = hemisphere(500, rng), hemisphere(500, rng)
    bsdf = render_models.bsdf_dict(model, PARAMS[model])
    forward, pdf = render_models.bsdf_values(bsdf, wi, wo)  # f_r cos(wo)
    backward, _ = render_models.bsdf_values(bsdf, wo, wi)
    f_forward, f_backward = forward / wo[:, 2], backward / wi[:, 2]
    assert np.allclose(f_forward, f_backward, rtol=2e-4)
    law = photometry.get_model(model).radiance_factor(PARAMS[model], wo[:, 2], wi[:, 2], np.sum(wi * wo, axis=1)) / np.pi
    assert np.allclose(forward, law, rtol=2e-4)
    assert np.allclose(pdf, wo[:, 2] / np.pi, rtol=1e-5)


def near_opposition(n, phase_deg, rng):
    """Unit view and light directions ``phase_deg`` apart about random axes, both above the surface (cos >= 0.15)."""
    view = hemisphere(4 * n, rng)
    axis = rng.normal(size=view.shape)
    axis -= np.sum(axis * view, axis=1, keepdims=True) * view
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    phase = np.radians(phase_deg)
    light = np.cos(phase) * view + np.sin(phase) * axis
    keep = (view[:, 2] >= 0.15) & (light[:, 2] >= 0.15)
    return view[keep][:n], light[keep][:n]


@pytest.mark.parametrize("phase_deg", [0.0, 0.01, 0.1, 1.0, 5.0])
def test_hapke_plugin_matches_the_law_near_opposition(variant, phase_deg):
    """The float32 plugin agrees with the float64 law to 2e-6 relative, also where psi is small.

    The renderer gets float32 directions; the reference is the law at the
    same directions, normalised in float64. An azimuth psi taken as the
    arccos of (cos g - cos_i cos_o) / (sin_i sin_o) in float32 is off by
    about 5e-4 rad near opposition, and the law then by up to 1e-3.
    """
    wi, wo = near_opposition(3000, phase_deg, np.random.default_rng(7))
    wi, wo = wi.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64)
    plugin, _ = render_models.bsdf_values(render_models.bsdf_dict("hapke", PARAMS["hapke"]), wi, wo)
    wi, wo = wi / np.linalg.norm(wi, axis=1, keepdims=True), wo / np.linalg.norm(wo, axis=1, keepdims=True)
    law = photometry.get_model("hapke").radiance_factor(PARAMS["hapke"], wo[:, 2], wi[:, 2], np.sum(wi * wo, axis=1), one_minus_cos_g=0.5 * np.sum((wi - wo) ** 2, axis=1)) / np.pi
    assert np.max(np.abs(plugin / law - 1.0)) < 2e-6


def quadrature_albedo(model, params, cos_incidence, n=400):
    """Directional-hemispherical albedo of the law by a midpoint rule over (cos_o, azimuth)."""
    cos_o = (np.arange(n) + 0.5) / n
    azimuth = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    cos_o, azimuth = np.meshgrid(cos_o, azimuth, indexing="ij")
    sin_i, sin_o = np.sqrt(1 - cos_incidence**2), np.sqrt(1 - cos_o**2)
    cos_g = cos_incidence * cos_o + sin_i * sin_o * np.cos(azimuth)
    b = photometry.get_model(model).radiance_factor(params, np.full_like(cos_o, cos_incidence), cos_o, cos_g)
    # albedo = int f_r cos_o dOmega, f_r = b / (pi cos_i), dOmega = dcos_o dazimuth.
    return float(np.mean(b / (np.pi * cos_incidence) * cos_o) * 2 * np.pi)


@pytest.mark.parametrize("model", list(photometry.MODELS))
def test_energy_albedo_below_one(variant, model):
    bsdf = render_models.bsdf_dict(model, PARAMS[model])
    for cos_incidence in (0.25, 0.6, 1.0):
        sampled = render_models.albedo_by_sampling(bsdf, cos_incidence)
        expected = quadrature_albedo(model, PARAMS[model], cos_incidence)
        assert sampled == pytest.approx(expected, rel=0.02)
        assert 0 < sampled < 1
    if model == "minnaert":
        # Minnaert with k < 1 is not energy conserving at grazing incidence: 2 A cos_i^(k-1) / (k + 1).
        assert quadrature_albedo(model, PARAMS[model], 0.1) == pytest.approx(2 * 0.5 * 0.1 ** (-0.3) / 1.7, rel=0.01)
        assert quadrature_albedo(model, PARAMS[model], 0.1) > 1
