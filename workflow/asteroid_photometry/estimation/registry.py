"""One way to call an estimator: read a set's observations, check there are enough, run the named method.

Every stage that fits (Table 1, the Monte Carlo, the geometry study, Table 2)
goes through :func:`run_estimator`; the methods and what each needs are
listed in :data:`ESTIMATORS`.
"""

from __future__ import annotations

import numpy as np

from asteroid_photometry import estimation
from asteroid_photometry.core.failures import check_npz, DataFailure

#: The estimators a config may name (key ``estimators``), in the order tables list them.
ESTIMATORS = ("varpro", "koizumi_lm", "iwano_linear")

#: A fit needs this many points with at least ``MIN_VIEWS_PER_POINT`` observations each (an albedo and k per point and the light).
MIN_FIT_POINTS = 3
MIN_VIEWS_PER_POINT = 3


def observations_from_arrays(arrays: dict) -> estimation.Observations:
    """The :class:`Observations` stored in an observations file's arrays."""
    return estimation.Observations(
        point_index=arrays["point_index"], normal_cam=arrays["normal_cam"], view_cam=arrays["view_cam"],
        brightness=arrays["brightness"], n_points=int(arrays["n_points"]),
    )


def load_observations(path) -> tuple[estimation.Observations, dict]:
    """A set's observations and all arrays of its file; raises the recorded :class:`DataFailure` of a failed set."""
    with np.load(path) as data:
        check_npz(data, path)
        arrays = {name: data[name] for name in data.files}
    return observations_from_arrays(arrays), arrays


def require_observations(obs: estimation.Observations) -> None:
    """Raise :class:`DataFailure` when the observations are too few to fit."""
    seen = int(np.count_nonzero(obs.observations_per_point >= MIN_VIEWS_PER_POINT)) if obs.n_obs else 0
    if seen < MIN_FIT_POINTS:
        raise DataFailure(
            f"too few observations to fit: {obs.n_obs} observations, {seen} points seen at least {MIN_VIEWS_PER_POINT} times "
            f"(at least {MIN_FIT_POINTS} needed)"
        )


def run_estimator(
    obs: estimation.Observations,
    method: str,
    *,
    known_k: float | None = None,
    variance=None,
    robust: bool = False,
    light_init=None,
    hold_light: bool = False,
) -> estimation.FitResult:
    """Run the estimator ``method`` on ``obs``.

    - ``varpro``: weighted by ``variance`` (per observation) when given; with
      ``robust`` a Cauchy loss and outlier rejection, for observations with
      outlying rows (a reconstructed cloud's mislocated samples).
    - ``koizumi_lm``: the paper's joint fit, unweighted, as the paper's;
      from ``light_init`` when given, and with ``hold_light`` the per-point
      albedo and k under that light, the light not fitted.
    - ``iwano_linear``: needs ``known_k``, the Minnaert k it assumes.
    """
    if hold_light and method != "koizumi_lm":
        raise ValueError(f"hold_light: only koizumi_lm fits the points under a given light, not {method!r}")
    if method == "varpro":
        if robust:
            return estimation.fit_varpro(obs, loss="cauchy", reject_outliers=True)
        return estimation.fit_varpro(obs, sigma=None if variance is None else np.sqrt(variance))
    if method == "koizumi_lm":
        if light_init is None and not hold_light:
            return estimation.fit_koizumi_lm(obs)
        return estimation.fit_koizumi_lm(obs, light_init=light_init, hold_light=hold_light)
    if method == "iwano_linear":
        if known_k is None:
            raise ValueError("iwano_linear needs the Minnaert k it assumes (known_k)")
        return estimation.fit_iwano_linear(obs, minnaert_k=known_k)
    raise ValueError(f"config key 'estimators': unknown estimator {method!r} (known: {', '.join(ESTIMATORS)})")
