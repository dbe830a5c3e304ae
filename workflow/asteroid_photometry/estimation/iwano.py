"""Iwano's baseline: one global albedo and a known Minnaert k, linear least squares.

With ``s = albedo**(1/k) * l`` the Minnaert law becomes linear in ``s``.
"""

from __future__ import annotations

import time

import numpy as np

from asteroid_photometry.estimation.core import FitResult, Observations
from asteroid_photometry.reflectance.laws import minnaert_brightness

# --------------------------------------------------------------------------
# Iwano's baseline
# --------------------------------------------------------------------------


def fit_iwano_linear(obs: Observations, minnaert_k: float) -> FitResult:
    """Iwano's estimator: one global albedo, known Minnaert k, linear least squares.

    With ``s = albedo**(1/k) * l`` the Minnaert law reads
    ``(b / cos_o**(k-1))**(1/k) = n . s``, so ``s`` solves
    ``min_s sum_j (n_j . s - (b_j / cos_o_j**(k-1))**(1/k))**2`` and
    ``l = s / |s|``, ``albedo = |s|**k``. Non-positive brightness (noise)
    goes through a signed power so that it stays unbiased in sign.

    Every point with at least one observation gets the same albedo and
    ``minnaert_k``; points without observations get NaN. ``cost`` is
    ``0.5 * sum (b - model)**2`` in brightness units, comparable with the LM fit.
    """
    start = time.perf_counter()
    minnaert_k = float(minnaert_k)
    if not np.isfinite(minnaert_k) or minnaert_k <= 0.0:
        raise ValueError(f"fit_iwano_linear: minnaert_k must be a positive number, got {minnaert_k}")
    if obs.n_obs < 3:
        raise ValueError(f"fit_iwano_linear needs at least 3 observations, got {obs.n_obs}")

    cos_o = obs.cos_emission
    reduced = obs.brightness / cos_o ** (minnaert_k - 1.0)
    target = np.sign(reduced) * np.abs(reduced) ** (1.0 / minnaert_k)
    s, _, rank, _ = np.linalg.lstsq(obs.normal_cam, target, rcond=None)
    s_norm = float(np.linalg.norm(s))
    if rank < 3 or s_norm == 0.0:
        raise ValueError(f"fit_iwano_linear: the normals do not span 3-D (rank {rank}) or s = 0")
    light = s / s_norm
    albedo = s_norm**minnaert_k

    model = minnaert_brightness(albedo, minnaert_k, obs.normal_cam @ light, cos_o)
    cost = 0.5 * float(np.sum((obs.brightness - model) ** 2))
    observed = obs.observations_per_point > 0
    elapsed = time.perf_counter() - start
    return FitResult(
        method="iwano_linear",
        light_dir_cam=light,
        albedo=np.where(observed, albedo, np.nan),
        minnaert_k=np.where(observed, minnaert_k, np.nan),
        n_points_fitted=int(np.count_nonzero(observed)),
        n_obs=obs.n_obs,
        cost=cost,
        n_iterations=1,
        nfev=1,
        success=True,
        message="linear least squares (numpy.linalg.lstsq)",
        fit_seconds=elapsed,
        solver="numpy.linalg.lstsq",
    )
