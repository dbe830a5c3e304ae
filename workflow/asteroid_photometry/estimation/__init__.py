"""Estimation: the light direction, albedo and Minnaert k from observations.

The public API, one import away (``from asteroid_photometry import estimation``):

- :mod:`.core`: :class:`Observations`, :class:`FitResult` and the light's
  tangent-plane parametrisation;
- :mod:`.koizumi`: the paper's joint Levenberg-Marquardt fit, and the fit of
  one k shared by all points;
- :mod:`.iwano`: Iwano's linear baseline (k known, one albedo);
- :mod:`.varpro`: the default estimator, variable projection;
- :mod:`.arrow`: the arrow-structured normal equations all three share;
- :mod:`.blocks`: the observations regrouped for streamed passes, and the
  brightness pass that varpro's steps and fisher's information share;
- :mod:`.light_search`: the grid search of the starting light that koizumi
  and varpro share;
- :mod:`.fisher`: the Fisher information and the Cramer-Rao bound;
- :mod:`.hierarchical`: the light with a k per point held to the body's and a gain per image;
- :mod:`.model_fit`: fits of the photometric model family;
- :mod:`.registry`: one way to run a named estimator on a set's observations;
- :mod:`.synthetic`: observations with a known truth, for tests and benchmarks.

Nothing here reads an image, a file of truth or anything from
:mod:`asteroid_photometry.evaluation`.
"""

from asteroid_photometry.estimation.arrow import arrow_covariance, solve_arrow_system
from asteroid_photometry.estimation.core import (
    angle_between_deg,
    FitResult,
    light_angle_deg,
    light_from_tangent,
    light_std_deg,
    Observations,
    tangent_from_light,
)
from asteroid_photometry.estimation.iwano import fit_iwano_linear
from asteroid_photometry.estimation.koizumi import (
    fit_koizumi_lm,
    fit_pooled_k,
    initial_albedo_and_k,
    KoizumiProblem,
    profile_cost,
    search_light,
)
from asteroid_photometry.estimation.synthetic import synthetic_observations
from asteroid_photometry.estimation.varpro import fit_varpro

__all__ = [
    "Observations",
    "FitResult",
    "KoizumiProblem",
    "light_from_tangent",
    "tangent_from_light",
    "light_angle_deg",
    "angle_between_deg",
    "fit_iwano_linear",
    "fit_koizumi_lm",
    "fit_pooled_k",
    "fit_varpro",
    "solve_arrow_system",
    "arrow_covariance",
    "light_std_deg",
    "initial_albedo_and_k",
    "profile_cost",
    "search_light",
    "synthetic_observations",
]
