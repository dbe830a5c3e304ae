"""The light and every law's parameters fitted back from synthetic observations; the direct law fit; Fisher information."""

import numpy as np
import pytest
from test_photometry import ITOKAWA_HAPKE

from asteroid_photometry import estimation
from asteroid_photometry.estimation import model_fit
from asteroid_photometry.reflectance import laws as photometry
from asteroid_photometry.world import cameras

# What each law frees per point and globally (the rest held at the truth): as in config.yaml.
PLACEMENT = {
    "lambert": {"per_point": ["albedo"]},
    "lommel_seeliger": {"per_point": ["albedo"]},
    "lunar_lambert": {"per_point": ["albedo", "lunar_l"]},
    "minnaert": {"per_point": ["albedo", "minnaert_k"]},
    "hapke": {"per_point": ["w"], "global": ["roughness_deg"]},
}
TRUTH = {
    "lambert": {"albedo": 0.6},
    "lommel_seeliger": {"albedo": 0.3},
    "lunar_lambert": {"albedo": 0.5, "lunar_l": 0.4},
    "minnaert": {"albedo": 0.5, "minnaert_k": 0.7},
    "hapke": ITOKAWA_HAPKE,
}


@pytest.fixture(scope="module")
def geometry():
    light = cameras.light_dir_cam(10.0)
    obs = estimation.synthetic_observations(150, 12, light, 0.5, 0.7, np.random.default_rng(5))
    return obs, light


@pytest.mark.parametrize("model", list(photometry.MODELS))
def test_identity_fit_recovers_light_and_parameters(geometry, model):
    obs, light = geometry
    spec = model_fit.FitSpec.from_config(model, PLACEMENT[model], TRUTH[model])
    # Start 4 degrees off, the parameters at their generic starts.
    fit = model_fit.fit_law_to_law(model, TRUTH[model], spec, obs.normal_cam, obs.view_cam, obs.point_index, obs.n_points, light, light_dir_start=cameras.light_dir_cam(6.0))
    assert fit.success, fit.message
    assert model_fit.light_error_deg(fit, light) < 1e-5
    for name, values in fit.per_point.items():
        assert np.max(np.abs(values[fit.fitted_points] - TRUTH[model][name])) < 1e-6, name
    for name, value in fit.global_.items():
        assert value == pytest.approx(TRUTH[model][name], abs=1e-5), name
    assert fit.residual_rms < 1e-8


def test_a_wrong_law_leaves_residuals_and_a_worse_bic(geometry):
    obs, light = geometry
    right = model_fit.fit_law_to_law("minnaert", TRUTH["minnaert"], model_fit.FitSpec.from_config("minnaert", PLACEMENT["minnaert"]), obs.normal_cam, obs.view_cam, obs.point_index, obs.n_points, light)
    wrong = model_fit.fit_law_to_law("minnaert", TRUTH["minnaert"], model_fit.FitSpec.from_config("lambert", PLACEMENT["lambert"]), obs.normal_cam, obs.view_cam, obs.point_index, obs.n_points, light)
    assert wrong.residual_rms > 1e-3 > right.residual_rms
    assert wrong.bic > right.bic


def test_direct_law_fit_minnaert_on_minnaert_gives_k_exactly(geometry):
    obs, light = geometry
    spec = model_fit.FitSpec("minnaert", per_point=("albedo",), global_=("minnaert_k",), start={"minnaert_k": 1.0}, fit_light=False)
    fit = model_fit.fit_law_to_law("minnaert", {"albedo": 0.45, "minnaert_k": 0.83}, spec, obs.normal_cam, obs.view_cam, obs.point_index, obs.n_points, light)
    assert fit.global_["minnaert_k"] == pytest.approx(0.83, abs=1e-10)
    assert np.allclose(fit.per_point["albedo"][fit.fitted_points], 0.45, atol=1e-10)
    assert np.allclose(fit.light_dir_cam, light)
    # Fitted to Hapke's law instead, k is not the Minnaert value it was started from.
    hapke = model_fit.fit_law_to_law("hapke", ITOKAWA_HAPKE, spec, obs.normal_cam, obs.view_cam, obs.point_index, obs.n_points, light)
    assert 0.3 < hapke.global_["minnaert_k"] < 1.0 and abs(hapke.global_["minnaert_k"] - 1.0) > 0.05


def test_fisher_information_separates_identifiable_from_not(geometry):
    obs, light = geometry
    sigma = 0.003
    per_point = model_fit.fisher_information(obs, model_fit.FitSpec.from_config("hapke", PLACEMENT["hapke"], ITOKAWA_HAPKE), light, ITOKAWA_HAPKE, sigma)
    assert per_point["w_std"] < 0.01 and per_point["roughness_deg_std"] < 1.0 and per_point["light_std_deg"] < 0.1
    # Roughness per point is ten times less certain than one for the body.
    rough_per_point = model_fit.fisher_information(obs, model_fit.FitSpec.from_config("hapke", {"per_point": ["w", "roughness_deg"]}, ITOKAWA_HAPKE), light, ITOKAWA_HAPKE, sigma)
    assert rough_per_point["roughness_deg_std"] > 5 * per_point["roughness_deg_std"]
    # At one phase angle the phase function and the opposition surge are one number each observation sees
    # nearly alike: all five free, their bounds are as wide as their ranges.
    everything = model_fit.fisher_information(
        obs, model_fit.FitSpec.from_config("hapke", {"per_point": ["w"], "global": ["roughness_deg", "hg_b", "hg_c", "b0", "h"]}, ITOKAWA_HAPKE),
        light, ITOKAWA_HAPKE, sigma,
    )
    assert everything["condition"] > 100 * per_point["condition"]
    assert everything["hg_c_std"] > 0.5 and everything["b0_std"] > 0.5
    # A Minnaert k per point is as well determined as in the paper's setting.
    minnaert = model_fit.fisher_information(obs, model_fit.FitSpec.from_config("minnaert", PLACEMENT["minnaert"]), light, TRUTH["minnaert"], sigma)
    assert minnaert["minnaert_k_std"] < 0.01


def test_a_spec_must_place_every_parameter():
    with pytest.raises(ValueError, match="not placed"):
        model_fit.FitSpec("minnaert", per_point=("albedo",))
    with pytest.raises(ValueError, match="placed twice"):
        model_fit.FitSpec("minnaert", per_point=("albedo", "minnaert_k"), global_=("minnaert_k",))
