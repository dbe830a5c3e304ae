"""The photometric laws: their limits and relations, reciprocity, the H function, the finite-difference Jacobian."""

import numpy as np
import pytest

from asteroid_photometry.reflectance import laws as photometry

ITOKAWA_HAPKE = dict(w=0.57, roughness_deg=26.0, hg_b=0.35, hg_c=0.6, b0=1.0, h=0.05)
PARAMS = {
    "lambert": dict(albedo=0.6),
    "lommel_seeliger": dict(albedo=0.3),
    "lunar_lambert": dict(albedo=0.5, lunar_l=0.4),
    "minnaert": dict(albedo=0.5, minnaert_k=0.7),
    "hapke": ITOKAWA_HAPKE,
}


def random_geometry(n, seed=0):
    """Cosines of random light and view directions above a surface with normal +z."""
    rng = np.random.default_rng(seed)

    def hemisphere():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 0.05
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    return photometry.geometry_cosines(np.array([0.0, 0.0, 1.0]), hemisphere(), hemisphere())


def test_models_reduce_to_each_other():
    cos_i, cos_o, cos_g = random_geometry(2000)
    law = {name: photometry.get_model(name) for name in photometry.MODELS}
    lambert = law["lambert"].radiance_factor({"albedo": 0.6}, cos_i, cos_o, cos_g)
    assert np.allclose(lambert, 0.6 * cos_i)
    lommel = law["lommel_seeliger"].radiance_factor({"albedo": 0.6}, cos_i, cos_o, cos_g)
    assert np.allclose(lommel, 1.2 * cos_i / (cos_i + cos_o))
    for lunar_l, expected in ((0.0, lambert), (1.0, lommel)):
        assert np.allclose(law["lunar_lambert"].radiance_factor({"albedo": 0.6, "lunar_l": lunar_l}, cos_i, cos_o, cos_g), expected)
    assert np.allclose(law["minnaert"].radiance_factor({"albedo": 0.6, "minnaert_k": 1.0}, cos_i, cos_o, cos_g), lambert)
    minnaert = law["minnaert"].radiance_factor({"albedo": 0.5, "minnaert_k": 0.7}, cos_i, cos_o, cos_g)
    assert np.allclose(minnaert, photometry.minnaert_brightness(0.5, 0.7, cos_i, cos_o), rtol=1e-12)
    assert not np.allclose(minnaert, lambert, rtol=1e-2)


def test_hapke_smooth_isotropic_single_scattering_limit_is_lommel_seeliger():
    cos_i, cos_o, cos_g = random_geometry(5000, seed=1)
    limit = dict(w=0.57, roughness_deg=0.0, hg_b=0.0, hg_c=1.0, b0=0.0, h=0.05, multiple_scattering=False)
    hapke = photometry.get_model("hapke").radiance_factor(limit, cos_i, cos_o, cos_g)
    lommel = photometry.get_model("lommel_seeliger").radiance_factor({"albedo": 0.57 / 8}, cos_i, cos_o, cos_g)
    assert np.max(np.abs(hapke - lommel)) < 1e-12
    # Each ingredient moves it away from the limit.
    for change in ({"roughness_deg": 26.0}, {"hg_b": 0.3}, {"b0": 1.0}, {"multiple_scattering": True}):
        moved = photometry.get_model("hapke").radiance_factor({**limit, **change}, cos_i, cos_o, cos_g)
        assert np.max(np.abs(moved - lommel)) > 1e-3, change


def test_h_function_matches_chandrasekhar_tables():
    # Chandrasekhar's H function for conservative isotropic scattering (w = 1):
    # H(0.5) = 2.0129, H(1) = 2.9078; Hapke (2002) claims 1 % for his approximation.
    h = photometry._chandrasekhar_h(np.array([0.5, 1.0]), 1.0 - 1e-12, photometry.NUMPY_OPS)
    assert np.allclose(h, [2.0129, 2.9078], rtol=0.01)
    assert np.allclose(photometry._chandrasekhar_h(np.array([0.3, 1.0]), 1e-9, photometry.NUMPY_OPS), 1.0)


@pytest.mark.parametrize("name", list(photometry.MODELS))
def test_every_law_is_reciprocal_and_finite(name):
    cos_i, cos_o, cos_g = random_geometry(3000, seed=2)
    law = photometry.get_model(name)
    forward = law.radiance_factor(PARAMS[name], cos_i, cos_o, cos_g) / cos_i
    backward = law.radiance_factor(PARAMS[name], cos_o, cos_i, cos_g) / cos_o
    assert np.all(np.isfinite(forward)) and np.all(forward > 0)
    assert np.allclose(forward, backward, rtol=1e-10, atol=0)


def test_hapke_given_psi_is_the_psi_of_the_cosines():
    """The renderer's measured azimuth psi and the one the law derives from the cosines give the same law."""
    rng = np.random.default_rng(3)
    light, view = (rng.normal(size=(2000, 3)) for _ in range(2))
    light[:, 2], view[:, 2] = np.abs(light[:, 2]) + 0.1, np.abs(view[:, 2]) + 0.1
    light, view = light / np.linalg.norm(light, axis=1, keepdims=True), view / np.linalg.norm(view, axis=1, keepdims=True)
    cos_i, cos_o, cos_g = photometry.geometry_cosines(np.array([0.0, 0.0, 1.0]), light, view)
    psi = np.abs(np.arctan2(view[:, 0] * light[:, 1] - view[:, 1] * light[:, 0], view[:, 0] * light[:, 0] + view[:, 1] * light[:, 1]))
    law = photometry.get_model("hapke")
    derived = law.radiance_factor(ITOKAWA_HAPKE, cos_i, cos_o, cos_g)
    assert np.allclose(law.radiance_factor(ITOKAWA_HAPKE, cos_i, cos_o, cos_g, psi=psi), derived, rtol=1e-9, atol=0)
    # The given psi is used: another one changes the roughness correction.
    assert np.max(np.abs(law.radiance_factor(ITOKAWA_HAPKE, cos_i, cos_o, cos_g, psi=np.pi - psi) / derived - 1)) > 1e-2


def test_finite_difference_jacobian_matches_the_analytic_minnaert_one():
    cos_i, cos_o, cos_g = random_geometry(1000, seed=3)
    keep = (cos_i > 0.1) & (cos_o > 0.1)
    cos_i, cos_o, cos_g = cos_i[keep], cos_o[keep], cos_g[keep]
    b, derivatives = photometry.get_model("minnaert").jacobian(PARAMS["minnaert"], cos_i, cos_o, cos_g, ["albedo", "minnaert_k", "cos_i", "cos_g"], step=1e-6, central=True)
    assert np.allclose(derivatives["albedo"], b / 0.5, rtol=1e-8)
    assert np.allclose(derivatives["minnaert_k"], b * np.log(cos_i * cos_o), rtol=1e-6, atol=1e-10)
    assert np.allclose(derivatives["cos_i"], 0.7 * b / cos_i, rtol=1e-5)
    assert np.all(derivatives["cos_g"] == 0.0)
    # Hapke's phase dependence shows in cos_g.
    _, hapke = photometry.get_model("hapke").jacobian(ITOKAWA_HAPKE, cos_i, cos_o, cos_g, ["cos_g", "w"])
    assert np.all(np.isfinite(hapke["cos_g"])) and np.abs(hapke["cos_g"]).max() > 0.01


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="minnaert_k"):
        photometry.get_model("minnaert").check({"albedo": 0.5})
    with pytest.raises(ValueError, match="'w'"):
        photometry.get_model("hapke").check({**ITOKAWA_HAPKE, "w": 1.5})
    with pytest.raises(ValueError, match="unknown photometric model"):
        photometry.get_model("oren_nayar")
