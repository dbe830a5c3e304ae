"""Variable projection: the Koizumi joint fit, fast, robust and with uncertainties.

An alternative estimator for the ``fit`` stage, beside
:func:`~asteroid_photometry.estimation.fit_koizumi_lm`: the same input
(:class:`~asteroid_photometry.estimation.Observations`), the same estimand (one
global light direction, an albedo and a Minnaert k per point, weighted least
squares on the brightness) and a :class:`VarproResult`, a
:class:`~asteroid_photometry.estimation.FitResult` that also carries standard
deviations.

Why it is fast. For a fixed light every point's albedo and k follow from a
2-parameter *linear* fit in log space,

    log b + log cos_o = log albedo + k (log cos_i + log cos_o),

solved in closed form for all points at once. Eliminating them leaves a
problem in the light's two tangent coordinates only (variable projection);
each Gauss-Newton step on it is one pass over the observations and a 2x2
solve (the Schur complement of the per-point blocks, Kaufman's projection).
The log-space weights ``(b / sigma)**2`` make it approximate the brightness
metric, so it lands next to the least-squares solution, and one or two
joint Gauss-Newton passes on the *brightness* residuals (weights
``1 / sigma**2``, the same arrow-structured algebra as the block LM in
``koizumi``) then reach the true weighted least-squares (maximum-likelihood
under Gaussian noise) estimate, the one ``fit_koizumi_lm`` finds.

Passes over the data are streamed: the rows are regrouped once into dense
(points x observations) blocks, one per observation count
(:class:`~.blocks.PointBlocks`), and every pass walks them in cache-sized chunks, so
per-point broadcasts and sums are plain axis operations and no array the
size of the data is made per iteration.

Stages of :func:`fit_varpro`:

1. start: a grid over the light's tangent coordinates on a subsample of
   points (:func:`~.light_search.grid_search`, the search
   ``koizumi.search_light`` also makes), scored by the brightness cost with
   closed-form per-point parameters, all lights of a batch in one
   vectorised evaluation; then the reduced problem on a larger subsample;
   skipped when ``light_init`` is given;
2. the reduced (log-space) problem on all points;
3. ``polish``: joint Gauss-Newton / Levenberg-Marquardt on the brightness
   residuals;
4. optional robustness: Huber or Cauchy loss through iteratively reweighted
   least squares (IRLS) weights in stages 2 and 3, and rejection of
   observations whose standardized residual exceeds a MAD-based threshold,
   followed by a refit;
5. uncertainty: ``J^T W J`` at the solution, inverted through its arrow
   structure (``arrow.arrow_covariance``): the light's 2x2 covariance in
   tangent coordinates and its angular standard deviation, and every
   point's marginal standard deviations of albedo and k.

Frames, units and the tangent chart follow ``core`` and the package
conventions.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from asteroid_photometry.estimation.arrow import arrow_covariance, solve_arrow_system
from asteroid_photometry.estimation.blocks import (
    CHUNK_ROWS,
    chunk_geometry,
    chunk_sum,
    HUBER,
    joint_pass,
    light_frame,
    Loss,
    LOSSES,
    PassSums,
    point_dot,
    PointBlocks,
    strided,
)
from asteroid_photometry.estimation.core import (
    COS_INCIDENCE_FLOOR,
    FitResult,
    INIT_K_RANGE,
    light_from_tangent,
    light_std_deg,
    Observations,
    tangent_from_light,
)
from asteroid_photometry.estimation.iwano import fit_iwano_linear
from asteroid_photometry.estimation.light_search import evenly_spaced, grid_search

__all__ = ["LOSSES", "VarproResult", "fit_varpro"]

# A pass keeps at most this many |standardized residual| samples for MAD scale estimates.
MAD_SAMPLES = 200_000
# Fits whose RMS relative residual is below this are exact (noiseless data): stop iterating.
EXACT_FIT_RELATIVE = 1e-12
# Noise scale floor relative to the typical brightness, so that noiseless data never divide by 0.
SCALE_FLOOR_RELATIVE = 1e-9
# IRLS sweeps per point and pass of the reduced problem with a robust loss: Huber ones from a
# plain fit first (only when there is no previous estimate), then the loss's own.
ROBUST_START_SWEEPS = 4
ROBUST_SWEEPS = 3
# Robust losses: step tolerance (chi-square units) of the linearly converging IRLS, and rounds of
# the noise scale (re-estimated by MAD) until it changes by less than SCALE_ROUND_CHANGE.
ROBUST_STEP_TOL = 1e-4
MAX_SCALE_ROUNDS = 4
SCALE_ROUND_CHANGE = 0.02
# A point's 2x2 block counts as singular below this relative determinant.
SINGULAR_RELATIVE = 1e-12


def _weighted_line(weight, x, y, ones):
    """Per-point weighted least-squares line ``y = ybar + k (x - xbar)`` of a chunk, closed form.

    Returns ``(ybar, k, xbar, s0, sxx, dx, dy, ok)`` with ``s0`` the weight
    sum, ``sxx`` the centred second moment, ``dx``, ``dy`` the centred data
    and ``ok`` where the slope is determined (k = 1 elsewhere).
    """
    s0 = weight @ ones
    ok = s0 > 0
    safe_s0 = np.where(ok, s0, 1.0)
    x_mean = point_dot(weight, x) / safe_s0
    y_mean = point_dot(weight, y) / safe_s0
    dx = x - x_mean[:, None]
    dy = y - y_mean[:, None]
    w_dx = weight * dx
    sxx = point_dot(w_dx, dx)
    sxy = point_dot(w_dx, dy)
    ok &= sxx > 1e-12 * s0
    k = np.where(ok, sxy / np.where(ok, sxx, 1.0), 1.0)
    return y_mean, k, x_mean, s0, sxx, dx, dy, ok


def _robust_line(loss: Loss, scale, previous_line, base_weight, inv_var, brightness, log_cos_o, x, y, ones):
    """IRLS per point of a chunk's log-space lines under a robust loss; returns the last weights and :func:`_weighted_line`.

    The sweeps start from ``previous_line`` (log albedo, k, each (P, 1)), or
    from a plain fit made robust with Huber weights first (convex) so that a
    redescending loss starts in the right basin. Residuals and weights come
    from the model brightness, not the observed one: an outlier 3x too
    bright would otherwise also get 9x the weight b**2. ``inv_var``: ``1 /
    sigma**2`` of the usable rows (zero elsewhere).
    """
    if previous_line is None:
        fit = _weighted_line(base_weight, x, y, ones)
        sweeps = [HUBER] * ROBUST_START_SWEEPS + [loss] * ROBUST_SWEEPS
    else:
        fit = None
        line = previous_line
        sweeps = [loss] * ROBUST_SWEEPS
    for sweep_loss in sweeps:
        if fit is not None:
            line = fit[0][:, None] - fit[1][:, None] * fit[2][:, None], fit[1][:, None]  # log albedo, k
        with np.errstate(over="ignore"):  # Minnaert in log space (x = log cos_i + log cos_o); not laws.minnaert_factor's bits
            model = np.exp(line[0] + line[1] * x - log_cos_o)
        z = (brightness - model) * np.sqrt(inv_var) / scale
        weight = inv_var * model * model * sweep_loss.weight_and_rho(z)[0]
        fit = _weighted_line(weight, x, y, ones)
    return weight, fit


def _reduced_pass(layout: PointBlocks, tangent, loss: Loss, scale: float, previous=None, sample_stride=0):
    """The log-space problem at a light: closed-form log albedo and k per point, and the light's Schur blocks.

    Per point, weighted least squares of ``y = log b + log cos_o`` on ``x =
    log cos_i + log cos_o`` with weights ``w = b**2 / sigma**2`` (times the
    IRLS weight of the residual under the previous per-point parameters,
    ``previous = (log_albedo, k)``, for a robust loss); rows with ``b <= 0``
    or unlit get no weight. The per-point parameters are centred, ``y = c_p
    + k_p (x - xbar_p)``, which makes U_p diagonal. Returns ``(sums,
    log_albedo, k, valid)``; the point gradient is zero by construction (the
    inner problem is solved exactly). ``sample_stride > 0`` keeps every
    so-many |standardized residual| for a MAD.
    """
    frame = light_frame(tangent)
    m = layout.n_points
    sums = PassSums(m)
    log_albedo, minnaert_k, valid = np.zeros(m), np.ones(m), np.zeros(m, bool)
    v_aa = v_ab = v_bb = g_a = g_b = 0.0
    for chunk in layout.chunks:
        sl = chunk.points
        ones = layout.ones(chunk.block.count)
        brightness = chunk.rows_of("brightness")
        log_cos_o = chunk.rows_of("log_cos_o")
        cos_i, lit, d_log_a, d_log_b = chunk_geometry(chunk, frame)
        positive = brightness > 0.0
        x = np.log(cos_i)
        x += log_cos_o
        y = np.log(np.maximum(brightness, 1e-300))
        y += log_cos_o
        base_weight = brightness * brightness
        base_weight *= layout.weight(chunk)
        base_weight *= lit & positive
        if loss.robust:
            previous_line = None if previous is None else (previous[0][sl, None], previous[1][sl, None])
            weight, fit = _robust_line(loss, scale, previous_line, base_weight, layout.weight(chunk) * (lit & positive), brightness, log_cos_o, x, y, ones)
        else:
            weight = base_weight
            fit = _weighted_line(weight, x, y, ones)
        y_mean, k, x_mean, s0, sxx, dx, dy, ok = fit
        residual = dy - k[:, None] * dx
        log_albedo[sl] = y_mean - k * x_mean
        minnaert_k[sl] = k
        valid[sl] = ok
        # Objective and MAD samples on the standardized (brightness-like) residual.
        chi2 = base_weight * residual
        chi2 *= residual
        if loss.robust:
            z_base = np.sqrt(base_weight) * residual
            sums.objective += scale * scale * float(np.sum(loss.weight_and_rho(z_base / scale)[1]))
            sums.chi2 += chunk_sum(chi2, ones)
        else:
            total = chunk_sum(chi2, ones)
            sums.objective += 0.5 * total
            sums.chi2 += total
        sums.norm += chunk_sum(base_weight, ones)
        sums.n_rows += int(np.count_nonzero(base_weight))
        if sample_stride:
            sums.samples.append(np.sqrt(strided(chi2[base_weight > 0], sample_stride)))
        # Jacobian of r = y - c - k (x - xbar): light columns -k dlog/dt, point columns -1 and -(x - xbar).
        kk = np.where(ok, k, 0.0)  # singular points drop out of the light problem
        w_a = weight * d_log_a
        w_b = weight * d_log_b
        sums.u11[sl] = np.where(ok, s0, 1.0)
        sums.u22[sl] = np.where(ok, sxx, 1.0)
        sums.wa1[sl] = kk * (w_a @ ones)
        sums.wa2[sl] = kk * point_dot(w_a, dx)
        sums.wb1[sl] = kk * (w_b @ ones)
        sums.wb2[sl] = kk * point_dot(w_b, dx)
        k2 = kk * kk
        v_aa += float(k2 @ point_dot(w_a, d_log_a))
        v_ab += float(k2 @ point_dot(w_a, d_log_b))
        v_bb += float(k2 @ point_dot(w_b, d_log_b))
        g_a -= float(kk @ point_dot(w_a, residual))
        g_b -= float(kk @ point_dot(w_b, residual))
    sums.v[:] = v_aa, v_ab, v_bb
    sums.g_light[:] = g_a, g_b
    return sums, log_albedo, minnaert_k, valid


def _keep_pass(layout: PointBlocks, tangent, albedo, minnaert_k, threshold, keep_rows):
    """Mark in ``keep_rows`` (n_obs,) the rows whose |standardized brightness residual| is <= ``threshold``."""
    frame = light_frame(tangent)
    for chunk in layout.chunks:
        sl = chunk.points
        log_cos_o = chunk.rows_of("log_cos_o")
        cos_i = (frame[0] @ chunk.normal).reshape(chunk.shape)
        x = np.log(np.maximum(cos_i, COS_INCIDENCE_FLOOR)) + log_cos_o
        with np.errstate(over="ignore", invalid="ignore"):  # the joint pass's Minnaert form (blocks.joint_pass)
            model = albedo[sl, None] * np.exp(minnaert_k[sl, None] * x - log_cos_o)
        inv_var = chunk.rows_of("inv_var")
        size = np.abs(model - chunk.rows_of("brightness")) * np.sqrt(layout.inv_var if inv_var is None else inv_var)
        keep_rows[chunk.block.rows[chunk.p0 : chunk.p1]] = size <= threshold


def _point_valid(sums: PassSums) -> np.ndarray:
    det = sums.u11 * sums.u22 - sums.u12 * sums.u12
    return (sums.u11 > 0) & (sums.u22 > 0) & (det > SINGULAR_RELATIVE * sums.u11 * sums.u22) & np.isfinite(det)


def _masked_blocks(sums: PassSums, valid, damping=0.0):
    """Blocks for the arrow solve with invalid points decoupled (identity block, zero coupling and gradient)."""
    factor = 1.0 + damping
    u11 = np.where(valid, sums.u11 * factor, 1.0)
    u22 = np.where(valid, sums.u22 * factor, 1.0)
    u12 = np.where(valid, sums.u12, 0.0)
    couplings = tuple(np.where(valid, value, 0.0) for value in (sums.wa1, sums.wa2, sums.wb1, sums.wb2))
    gradient = (np.where(valid, sums.g1, 0.0), np.where(valid, sums.g2, 0.0))
    v_aa, v_ab, v_bb = sums.v
    return (v_aa * factor, v_ab, v_bb * factor), (u11, u12, u22), couplings, tuple(sums.g_light), gradient


def _step_chi2(sums, valid, step_light, step_1, step_2, damping):
    """delta^T H delta (undamped H) of a step solving (H + damping diag H) delta = -g."""
    gradient_dot = float(sums.g_light @ step_light) + float(np.sum(np.where(valid, sums.g1 * step_1 + sums.g2 * step_2, 0.0)))
    damped = damping * (
        sums.v[0] * step_light[0] ** 2
        + sums.v[2] * step_light[1] ** 2
        + float(np.sum(np.where(valid, sums.u11 * step_1 * step_1 + sums.u22 * step_2 * step_2, 0.0)))
    )
    return -gradient_dot - damped


def _exact(sums: PassSums) -> bool:
    return sums.norm > 0 and sums.chi2 <= (EXACT_FIT_RELATIVE**2) * sums.norm


# --------------------------------------------------------------------------
# Solvers
# --------------------------------------------------------------------------


@dataclasses.dataclass
class _SolveLog:
    passes: int = 0
    iterations: int = 0
    message: str = ""
    success: bool = True


def _solve_reduced(layout, tangent, loss, scale, variance_scale, max_iterations, step_tol, log: _SolveLog, stride=0):
    """Gauss-Newton / LM on the light's tangent coordinates with albedo and k projected out (log space)."""
    tangent = np.asarray(tangent, dtype=np.float64).copy()
    state = _reduced_pass(layout, tangent, loss, scale, None, stride)
    log.passes += 1
    if loss.robust:  # a second pass with IRLS weights from the first one's per-point parameters
        state = _reduced_pass(layout, tangent, loss, scale, state[1:3], stride)
        log.passes += 1
    damping = 0.0
    for _ in range(max_iterations):
        sums, log_albedo, minnaert_k, valid = state
        if _exact(sums):
            log.message = "reduced problem: exact fit"
            break
        light_block, point_blocks, couplings, g_light, _ = _masked_blocks(sums, valid)
        light_block = (light_block[0] * (1.0 + damping), light_block[1], light_block[2] * (1.0 + damping))
        zero = np.zeros(layout.n_points)
        step, _, _ = solve_arrow_system(light_block, point_blocks, couplings, g_light, (zero, zero))
        if not np.all(np.isfinite(step)):
            log.message, log.success = "reduced problem: singular light system", False
            break
        chi2 = _step_chi2(sums, np.zeros(layout.n_points, bool), step, zero, zero, damping) / variance_scale(sums)
        if chi2 <= step_tol:
            log.message = "reduced problem: step below tolerance"
            break
        trial = _reduced_pass(layout, tangent + step, loss, scale, (log_albedo, minnaert_k), stride)
        log.passes += 1
        log.iterations += 1
        if np.isfinite(trial[0].objective) and trial[0].objective <= sums.objective:
            tangent, state = tangent + step, trial
            damping = 0.0 if damping < 1e-6 else damping / 10.0
        else:
            damping = max(1e-4, damping * 10.0)
            if damping > 1e8:
                log.message = "reduced problem: the cost cannot be lowered further"
                break
    else:
        log.message = f"reduced problem: {max_iterations} iterations"
    return tangent, state


def _solve_joint(layout, tangent, albedo, minnaert_k, valid, loss, scale, variance_scale, max_iterations, step_tol, log, stride=0):
    """Gauss-Newton / LM on all parameters (brightness residuals), steps through the arrow structure."""
    tangent, albedo, minnaert_k = np.array(tangent, float), albedo.copy(), minnaert_k.copy()
    sums = joint_pass(layout, tangent, albedo, minnaert_k, loss, scale, stride)
    log.passes += 1
    damping = 0.0
    for _ in range(max_iterations):
        point_valid = valid & _point_valid(sums)
        if _exact(sums):
            log.message = "exact fit"
            break
        blocks = _masked_blocks(sums, point_valid, damping)
        step_light, step_albedo, step_k = solve_arrow_system(*blocks)
        if not (np.all(np.isfinite(step_light)) and np.all(np.isfinite(step_albedo[point_valid]))):
            log.message, log.success = "singular normal equations", False
            break
        chi2 = _step_chi2(sums, point_valid, step_light, step_albedo, step_k, damping) / variance_scale(sums)
        if chi2 <= step_tol:
            log.message = "step below tolerance"
            break
        trial_albedo = np.where(point_valid, albedo + step_albedo, albedo)
        trial_k = np.where(point_valid, minnaert_k + step_k, minnaert_k)
        trial = joint_pass(layout, tangent + step_light, trial_albedo, trial_k, loss, scale, stride)
        log.passes += 1
        log.iterations += 1
        if np.isfinite(trial.objective) and trial.objective <= sums.objective:
            tangent, albedo, minnaert_k, sums = tangent + step_light, trial_albedo, trial_k, trial
            damping = 0.0 if damping < 1e-6 else damping / 10.0
        else:
            damping = max(1e-4, damping * 10.0)
            if damping > 1e8:
                log.message = "the cost cannot be lowered further"
                break
    else:
        log.message = f"{max_iterations} iterations"
    return tangent, albedo, minnaert_k, sums


# --------------------------------------------------------------------------
# Starting light
# --------------------------------------------------------------------------


def _profile_costs(layout: PointBlocks, tangents: np.ndarray) -> np.ndarray:
    """Brightness cost of many lights at once, each with closed-form log-space albedo and k per point.

    The score of ``koizumi.profile_cost`` (k clipped to ``INIT_K_RANGE``),
    vectorised over lights, except that unlit rows are predicted dark, the
    weights carry ``1 / sigma**2`` and a singular point gets k = 1 with its
    own rows' level (albedo 1 with none) rather than the others' mean albedo:
    the two are not bit-for-bit the same score.
    """
    lights = light_from_tangent(tangents)  # (L, 3)
    n_lights = len(lights)
    costs = np.zeros(n_lights)
    for block in layout.blocks:
        n, count = block.rows.shape
        cos_i = (lights @ block.normal).reshape(n_lights, n, count)
        brightness, log_cos_o = block.brightness, block.log_cos_o
        inv_var = layout.inv_var if block.inv_var is None else block.inv_var
        positive = brightness > 0.0
        y = np.log(np.where(positive, brightness, 1.0)) + log_cos_o
        usable = (cos_i > COS_INCIDENCE_FLOOR) & positive
        x = np.log(np.where(usable, cos_i, 1.0)) + log_cos_o
        weight = (inv_var * brightness * brightness) * usable
        s0 = weight.sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            x_mean = np.einsum("lpc,lpc->lp", weight, x) / s0
            y_mean = np.einsum("lpc,pc->lp", weight, y) / s0
            dx = x - x_mean[..., None]
            w_dx = weight * dx
            sxx = np.einsum("lpc,lpc->lp", w_dx, dx)
            sxy = np.einsum("lpc,pc->lp", w_dx, y)  # sum w dx (y - ybar) = sum w dx y
            regular = (s0 > 0) & (sxx > 1e-12 * s0)
            k = np.clip(np.where(regular, sxy / sxx, 1.0), *INIT_K_RANGE)
            log_albedo = np.where(s0 > 0, y_mean - k * x_mean, 0.0)
            model = np.exp(log_albedo[..., None] + k[..., None] * x - log_cos_o)  # Minnaert in log space, not laws.minnaert_factor's bits
        model[~usable] = 0.0
        model -= brightness
        model *= model
        costs += 0.5 * (model.reshape(n_lights, -1) @ np.broadcast_to(inv_var, brightness.shape).ravel())
    return costs


def _grid_search(layout: PointBlocks, guess_tangent, half_width=0.8, n_grid=17, n_refine=2, batch_elements=1 << 18):
    """:func:`~.light_search.grid_search` by :func:`_profile_costs`, each level's best node its own, lights scored in batches."""

    def score(candidates):
        batch = max(1, batch_elements // max(layout.n_rows, 1))
        return np.concatenate([_profile_costs(layout, candidates[i : i + batch]) for i in range(0, len(candidates), batch)])

    return grid_search(score, guess_tangent, half_width=half_width, n_grid=n_grid, n_refine=n_refine, keep_best=False)


def _lambert_guess(obs: Observations, rows):
    """Iwano's linear fit with k = 1 on some rows: a cheap light guess (tangent coordinates), or None."""
    if rows.size < 3:
        return None
    sub = Observations(obs.point_index[rows], obs.normal_cam[rows], obs.view_cam[rows], obs.brightness[rows], obs.n_points)
    try:
        return tangent_from_light(fit_iwano_linear(sub, 1.0).light_dir_cam)
    except ValueError:
        return None


# --------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class VarproResult(FitResult):
    """A :class:`FitResult` with the uncertainties of :func:`fit_varpro`'s estimate.

    Per point (NaN where not fitted): ``albedo_std``, ``minnaert_k_std``
    and ``albedo_k_cov``, the marginal (light uncertainty included)
    standard deviations and covariance. ``light_cov_tangent`` (2x2): the
    light's covariance in tangent coordinates (``core.light_from_tangent``);
    ``light_std_deg``: the RMS angular error it implies
    (``core.light_std_deg``). ``noise_sigma``: the brightness noise
    standard deviation used, given or estimated (``sigma_estimated``), NaN
    when a per-observation sigma was given; ``reduced_chi2``: weighted sum of
    squared residuals over the degrees of freedom (about 1 when a given
    sigma is right). ``observation_used`` (n_obs,): rows that entered the
    final fit (False for rejected outliers and points not fitted);
    ``n_rejected``: outliers rejected. ``cost`` is, as for every estimator,
    0.5 * the unweighted sum of squared brightness residuals over the rows
    used; ``weighted_cost`` the minimised objective (with 1/sigma**2 weights
    and the robust loss). ``stage_seconds`` and ``stage_passes``: time and
    passes over the data per stage.
    """

    albedo_std: np.ndarray | None = None
    minnaert_k_std: np.ndarray | None = None
    albedo_k_cov: np.ndarray | None = None
    light_cov_tangent: np.ndarray | None = None
    light_std_deg: float = float("nan")
    noise_sigma: float = float("nan")
    sigma_estimated: bool = False
    reduced_chi2: float = float("nan")
    weighted_cost: float = float("nan")
    observation_used: np.ndarray | None = None
    n_rejected: int = 0
    loss: str = "linear"
    stage_seconds: dict = dataclasses.field(default_factory=dict)
    stage_passes: dict = dataclasses.field(default_factory=dict)

    @property
    def light_tangent(self) -> np.ndarray:
        return tangent_from_light(self.light_dir_cam)


# --------------------------------------------------------------------------
# The estimator's stages
# --------------------------------------------------------------------------


def _inverse_variance(obs: Observations, sigma):
    if sigma is None:
        return 1.0
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.ndim == 0:
        if not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"fit_varpro: sigma must be a positive number, got {float(sigma)!r}")
        return 1.0 / float(sigma) ** 2
    if sigma.shape != (obs.n_obs,):
        raise ValueError(f"fit_varpro: sigma must be a scalar or have shape ({obs.n_obs},), got {sigma.shape}")
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        raise ValueError("fit_varpro: every sigma must be finite and > 0")
    return 1.0 / sigma**2


@dataclasses.dataclass
class _Estimate:
    """Light (tangent coordinates), flat per-point albedo and k, the points the log-space fit determined, and the last pass's sums."""

    tangent: np.ndarray
    albedo: np.ndarray
    minnaert_k: np.ndarray
    valid: np.ndarray
    sums: PassSums


@dataclasses.dataclass
class _Solver:
    """What the stages of :func:`fit_varpro` share: the layout, the noise model, the losses and the tolerances.

    ``loss`` is the loss asked for, ``fit_loss`` the one fitted now: Huber
    while outliers are looked for under a linear ``loss`` (a least-squares
    fit bends towards outliers and hides them), ``loss`` once rejection has
    started. ``stride``: every so-many |standardized residual| of a pass is
    kept for a MAD (0: none). ``reduced_tol``: the step tolerance of the
    log-space problem on all points, fixed at the start.
    """

    obs: Observations
    layout: PointBlocks
    inv_var: float | np.ndarray
    sigma_known: bool
    loss: Loss
    fit_loss: Loss
    stride: int
    scale_floor: float
    max_iterations: int
    step_tol: float
    polish: bool
    reduced_tol: float = 0.0

    @classmethod
    def create(cls, obs, *, sigma, loss, f_scale, reject_outliers, rejection_threshold, min_observations, max_iterations, step_tol, polish, chunk_rows):
        loss_fn = Loss(loss, f_scale)
        if not rejection_threshold > 0:
            raise ValueError(f"fit_varpro: rejection_threshold must be > 0, got {rejection_threshold!r}")
        inv_var = _inverse_variance(obs, sigma)
        layout = PointBlocks(obs, min_observations=min_observations, inv_var=inv_var, chunk_rows=chunk_rows)
        if layout.n_points == 0 or layout.n_rows < layout.n_params:
            raise ValueError(
                f"fit_varpro: {layout.n_rows} usable observations of {layout.n_points} points "
                f"cannot determine {layout.n_params} unknowns"
            )
        fit_loss = HUBER if reject_outliers and not loss_fn.robust else loss_fn
        solver = cls(
            obs=obs,
            layout=layout,
            inv_var=inv_var,
            sigma_known=sigma is not None,
            loss=loss_fn,
            fit_loss=fit_loss,
            stride=max(1, layout.n_rows // MAD_SAMPLES) if (fit_loss.robust or reject_outliers) else 0,
            # Noise-scale floor in standardized units, so that noiseless data never divide by zero.
            scale_floor=SCALE_FLOOR_RELATIVE * layout.typical_brightness,
            max_iterations=max_iterations,
            step_tol=step_tol,
            polish=polish,
        )
        # The reduced problem only has to bring the polish close: 0.1 sigma of the light is plenty.
        solver.reduced_tol = max(solver.step_tolerance(), 1e-2) if polish else solver.step_tolerance()
        return solver

    @property
    def estimates_scale(self) -> bool:
        """Whether the robust loss's scale comes from a MAD (sigma unknown)."""
        return self.fit_loss.robust and not self.sigma_known

    def variance_scale(self, sums) -> float:
        """The noise variance in units of the weights: 1 if sigma is known, else estimated."""
        if self.sigma_known:
            return 1.0
        dof = max(sums.n_rows - sums.n_params, 1)
        value = sums.mad_sigma() ** 2 if self.fit_loss.robust else sums.chi2 / dof
        return max(value, self.scale_floor**2)

    def robust_scale(self, sums) -> float:
        return max(sums.mad_sigma(), self.scale_floor) if self.estimates_scale else 1.0

    def step_tolerance(self) -> float:
        # IRLS converges linearly: with a robust loss, stop at steps of 0.01 sigma.
        return max(self.step_tol, ROBUST_STEP_TOL) if self.fit_loss.robust else self.step_tol

    def solve_reduced(self, layout, tangent, tol, log):
        """The log-space problem on ``layout`` (all points or a subsample) from ``tangent``."""
        scale = 1.0
        if self.estimates_scale:  # the scale from the non-robust residuals at the start
            scale = self.robust_scale(_reduced_pass(layout, tangent, self.fit_loss, 1.0, None, max(1, layout.n_rows // MAD_SAMPLES))[0])
            log.passes += 1
        return _solve_reduced(layout, tangent, self.fit_loss, scale, self.variance_scale, self.max_iterations, tol, log, self.stride)

    def solve_joint(self, estimate: _Estimate, scale, log) -> _Estimate:
        """The joint problem on all points, in rounds of the robust scale (one round when it is fixed)."""
        tangent, albedo, minnaert_k = estimate.tangent, estimate.albedo, estimate.minnaert_k
        for _ in range(MAX_SCALE_ROUNDS):
            tangent, albedo, minnaert_k, sums = _solve_joint(
                self.layout, tangent, albedo, minnaert_k, estimate.valid, self.fit_loss, scale, self.variance_scale,
                self.max_iterations, self.step_tolerance(), log, self.stride,
            )
            new_scale = self.robust_scale(sums)
            if not self.estimates_scale or abs(new_scale - scale) <= SCALE_ROUND_CHANGE * scale:
                break
            scale = new_scale
        return _Estimate(tangent, albedo, minnaert_k, estimate.valid, sums)


def _start_light(solver: _Solver, light_init, search_points, grid_points, log):
    """Stage 1: the starting light's tangent coordinates (grid search or Iwano's guess, then a subsample), or ``light_init``'s."""
    layout = solver.layout
    if light_init is None or (isinstance(light_init, str) and light_init == "iwano"):
        sub_ids = evenly_spaced(np.arange(layout.n_points), search_points)
        grid_layout = layout.subset(evenly_spaced(sub_ids, grid_points))
        guess = _lambert_guess(solver.obs, grid_layout.rows())
        if light_init is None:
            tangent = _grid_search(grid_layout, guess)
        elif guess is None:
            raise ValueError("fit_varpro: Iwano's linear fit failed on the subsample (light_init='iwano')")
        else:
            tangent = guess
        if layout.n_points > sub_ids.size:
            tangent, _ = solver.solve_reduced(layout.subset(sub_ids), tangent, solver.step_tol, log)
        return tangent
    if isinstance(light_init, str):
        raise ValueError(f"fit_varpro: light_init must be None, 'iwano' or a (3,) vector, got {light_init!r}")
    light = np.asarray(light_init, dtype=np.float64)
    if light.shape != (3,) or not np.all(np.isfinite(light)):
        raise ValueError(f"fit_varpro: light_init must be a finite (3,) vector, got {light_init!r}")
    return tangent_from_light(light / np.linalg.norm(light))


def _reduced_estimate(solver: _Solver, tangent, log) -> _Estimate:
    """Stage 2: the reduced (log-space) problem on all points."""
    tangent, (sums, log_albedo, minnaert_k, valid) = solver.solve_reduced(solver.layout, tangent, solver.reduced_tol, log)
    return _Estimate(tangent, np.exp(log_albedo), minnaert_k, valid, sums)


def _polish(solver: _Solver, estimate: _Estimate, log) -> _Estimate:
    """Stage 3: the joint problem on the brightness residuals, or (``polish`` False) only one joint pass at the estimate."""
    scale = solver.robust_scale(estimate.sums)
    if solver.polish:
        return solver.solve_joint(estimate, scale, log)
    sums = joint_pass(solver.layout, estimate.tangent, estimate.albedo, estimate.minnaert_k, solver.fit_loss, scale, solver.stride)
    log.passes += 1
    return dataclasses.replace(estimate, sums=sums)


def _reject_outliers(solver: _Solver, estimate: _Estimate, rejection_threshold, max_rounds, log) -> _Estimate:
    """Stage 4: reject observations beyond ``rejection_threshold`` MAD sigmas and refit, until nothing changes."""
    for _ in range(int(max_rounds)):
        threshold = rejection_threshold * max(estimate.sums.mad_sigma(), solver.scale_floor)
        keep_rows = np.zeros(solver.obs.n_obs, bool)
        _keep_pass(solver.layout, estimate.tangent, estimate.albedo, estimate.minnaert_k, threshold, keep_rows)
        log.passes += 1
        if solver.layout.set_keep(keep_rows) == 0 and solver.fit_loss is solver.loss:
            break
        solver.fit_loss = solver.loss  # the refits use the loss asked for (the Huber fit only found the outliers)
        estimate = _polish(solver, estimate if solver.polish else _reduced_estimate(solver, estimate.tangent, log), log)
    return estimate


def _uncertainty(solver: _Solver, estimate: _Estimate) -> dict:
    """Stage 5: the covariances from ``J^T W J`` at the estimate, scaled by the noise variance; a dict of result fields."""
    sums = estimate.sums
    point_valid = estimate.valid & _point_valid(sums)
    light_block, point_blocks, couplings, _, _ = _masked_blocks(sums, point_valid)
    light_cov, var_albedo, var_k, cov_albedo_k = arrow_covariance(light_block, point_blocks, couplings)
    n_params_used = 2 + 2 * int(np.count_nonzero(point_valid))
    dof = max(sums.n_rows - n_params_used, 1)
    noise_variance = solver.variance_scale(sums)
    light_cov = light_cov * noise_variance
    with np.errstate(invalid="ignore"):
        albedo_std, k_std = np.sqrt(var_albedo * noise_variance), np.sqrt(var_k * noise_variance)
    if solver.sigma_known:
        noise_sigma = float(np.sqrt(1.0 / solver.inv_var)) if np.ndim(solver.inv_var) == 0 else float("nan")
    else:
        noise_sigma = float(np.sqrt(noise_variance))
    return dict(
        point_valid=point_valid,
        albedo_std=albedo_std,
        minnaert_k_std=k_std,
        albedo_k_cov=cov_albedo_k * noise_variance,
        light_cov_tangent=light_cov,
        noise_sigma=noise_sigma,
        reduced_chi2=float(sums.chi2 / dof),
        observation_used=solver.layout.rows_used(solver.obs.n_obs, point_valid),
    )


def _result(solver: _Solver, estimate: _Estimate, uncertainty: dict, logs, start, seconds, passes) -> VarproResult:
    """The :class:`VarproResult`: per-point values scattered to the Observations' points (NaN where not determined)."""
    search_log, reduced_log, joint_log = logs
    point_valid = uncertainty.pop("point_valid")

    def per_point(values):
        return solver.layout.per_point(np.where(point_valid, values, np.nan))

    messages = [reduced_log.message] + ([joint_log.message] if solver.polish else [])
    success = reduced_log.success and (joint_log.success if solver.polish else True)
    return VarproResult(
        method="varpro",
        light_dir_cam=light_from_tangent(estimate.tangent),
        albedo=per_point(estimate.albedo),
        minnaert_k=per_point(estimate.minnaert_k),
        n_points_fitted=int(np.count_nonzero(point_valid)),
        n_obs=int(np.count_nonzero(uncertainty["observation_used"])),
        cost=float(estimate.sums.cost),
        n_iterations=search_log.iterations + reduced_log.iterations + joint_log.iterations,
        nfev=reduced_log.passes + joint_log.passes,
        success=bool(success),
        message="; ".join(message for message in messages if message),
        fit_seconds=time.perf_counter() - start,
        solver="variable projection (log space) + joint Gauss-Newton polish, block-Schur (numpy, streamed)",
        albedo_std=per_point(uncertainty.pop("albedo_std")),
        minnaert_k_std=per_point(uncertainty.pop("minnaert_k_std")),
        albedo_k_cov=per_point(uncertainty.pop("albedo_k_cov")),
        light_std_deg=light_std_deg(estimate.tangent, uncertainty["light_cov_tangent"]),
        sigma_estimated=not solver.sigma_known,
        weighted_cost=float(estimate.sums.objective),
        n_rejected=solver.layout.n_rejected(),
        loss=solver.loss.name,
        stage_seconds=seconds,
        stage_passes=passes,
        **uncertainty,
    )


# --------------------------------------------------------------------------
# The estimator
# --------------------------------------------------------------------------


def fit_varpro(
    obs: Observations,
    *,
    sigma=None,
    loss: str = "linear",
    f_scale: float | None = None,
    reject_outliers: bool = False,
    rejection_threshold: float = 4.0,
    max_rejection_rounds: int = 3,
    light_init=None,
    polish: bool = True,
    min_observations: int = 2,
    max_iterations: int = 30,
    step_tol: float = 1e-6,
    search_points: int = 2000,
    grid_points: int = 200,
    chunk_rows: int = CHUNK_ROWS,
) -> VarproResult:
    """Fit one light and a per-point albedo and Minnaert k by variable projection, then polish.

    Minimises ``sum_j rho(r_j / sigma_j)`` with ``r_j = albedo_p cos_i**k_p
    cos_o**(k_p - 1) - b_j`` (rho the square for ``loss="linear"``: weighted
    least squares, the maximum-likelihood estimate under Gaussian noise).

    Parameters
    ----------
    obs : Observations
        As for ``koizumi.fit_koizumi_lm``; rows may come in any order.
    sigma : None, float or (n_obs,) array
        Brightness noise standard deviation, one for all or per observation
        (e.g. ``np.sqrt(noise.observation_variance(obs.brightness, sensor))``).
        None: unknown; one sigma is estimated from the residuals (residual
        variance over the degrees of freedom; the MAD for a robust loss)
        and the uncertainties are scaled by it.
    loss : {"linear", "huber", "cauchy"}
        Robust losses act through IRLS weights in both stages.
    f_scale : float
        The loss threshold in units of the standardized residual ``r /
        sigma``; defaults 1.345 (Huber) and 2.3849 (Cauchy). With ``sigma``
        None the scale is re-estimated from the MAD of the residuals.
    reject_outliers, rejection_threshold, max_rejection_rounds
        After the fit, observations whose standardized residual exceeds
        ``rejection_threshold`` times ``1.4826 * MAD`` (over the kept
        observations) are dropped and the fit redone, until no observation
        changes status or ``max_rejection_rounds`` rounds. Observations are
        rejected one by one, never whole points, but a point left with
        fewer than two is not fitted (NaN). With ``loss="linear"`` the
        outliers are found after a Huber fit (a least-squares fit bends
        towards them and hides them), and the kept observations are then
        refitted by least squares.
    light_init : None, "iwano" or (3,) array
        None: grid search and the reduced problem on a subsample
        (``grid_points`` and ``search_points`` points). "iwano": Iwano's
        Lambert light on the subsample instead of the grid. A vector: that
        light (camera frame, ``l_z < 0``).
    polish : bool
        Run the joint passes on the brightness residuals (True) or return
        the log-space estimate (False; its uncertainties are still computed
        from the brightness Jacobian).
    max_iterations, step_tol
        Per stage. A stage stops when its Gauss-Newton step ``delta`` has
        ``delta^T H delta <= step_tol`` in units of the noise variance (the
        step is far below the estimate's standard deviation), when the
        residuals are exact to 1e-12 (noiseless data), or when no damped
        step lowers the objective.
    chunk_rows : int
        Rows per chunk of a streamed pass.

    Returns
    -------
    VarproResult
        ``method="varpro"``; see :class:`VarproResult` for the uncertainty
        fields. ``nfev`` counts passes over all the data; ``n_iterations``
        the accepted and rejected steps of both stages.
    """
    start = time.perf_counter()
    solver = _Solver.create(
        obs, sigma=sigma, loss=loss, f_scale=f_scale, reject_outliers=reject_outliers, rejection_threshold=rejection_threshold,
        min_observations=min_observations, max_iterations=max_iterations, step_tol=step_tol, polish=polish, chunk_rows=chunk_rows,
    )
    logs = search_log, reduced_log, joint_log = _SolveLog(), _SolveLog(), _SolveLog()
    seconds, passes = {}, {}

    tick = time.perf_counter()
    tangent = _start_light(solver, light_init, search_points, grid_points, search_log)
    seconds["start"] = time.perf_counter() - tick
    passes["start_subsample"] = search_log.passes

    tick = time.perf_counter()
    estimate = _reduced_estimate(solver, tangent, reduced_log)
    seconds["reduced"] = time.perf_counter() - tick
    passes["reduced"] = reduced_log.passes

    tick = time.perf_counter()
    estimate = _polish(solver, estimate, joint_log)
    if reject_outliers:
        estimate = _reject_outliers(solver, estimate, rejection_threshold, max_rejection_rounds, joint_log)
    seconds["polish"] = time.perf_counter() - tick
    passes["polish"] = joint_log.passes

    tick = time.perf_counter()
    uncertainty = _uncertainty(solver, estimate)
    seconds["uncertainty"] = time.perf_counter() - tick
    return _result(solver, estimate, uncertainty, logs, start, seconds, passes)
