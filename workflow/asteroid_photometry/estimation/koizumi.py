"""The paper's estimator: one global light plus an albedo and a Minnaert k per point.

:func:`fit_koizumi_lm` fits them jointly by Levenberg-Marquardt to the
brightness residuals ``b - albedo * cos_i**k * cos_o**(k - 1)``; the normal
equations have the arrow structure of :mod:`.arrow`. :func:`fit_pooled_k`
fits one k shared by all points.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.optimize
import scipy.sparse

from asteroid_photometry.estimation.arrow import solve_arrow_system
from asteroid_photometry.estimation.core import (
    _point_layout,
    COS_INCIDENCE_FLOOR,
    FitResult,
    INIT_K_RANGE,
    light_from_tangent,
    Observations,
    tangent_from_light,
)
from asteroid_photometry.estimation.iwano import fit_iwano_linear
from asteroid_photometry.estimation.light_search import evenly_spaced, grid_search
from asteroid_photometry.reflectance.laws import minnaert_factor

# --------------------------------------------------------------------------
# Koizumi et al.: joint non-linear fit
# --------------------------------------------------------------------------


class KoizumiProblem:
    """Residuals and Jacobian of the joint fit, for the fitted points of ``obs``.

    Parameter vector ``x = [a, b, albedo_0 .. albedo_{m-1}, k_0 .. k_{m-1}]``
    with ``(a, b)`` the light's tangent coordinates (:func:`light_from_tangent`)
    and ``m`` the number of fitted points (those with at least
    ``min_observations`` rows), in increasing point order. Residuals are
    ``model - b`` for the rows of fitted points.
    """

    def __init__(self, obs: Observations, min_observations: int = 2, cos_floor: float = COS_INCIDENCE_FLOOR):
        self.obs = obs
        self.cos_floor = float(cos_floor)
        self.fitted, local_of_point, row_used = _point_layout(obs, min_observations)
        self.n_fitted = int(np.count_nonzero(self.fitted))
        self.n_params = 2 + 2 * self.n_fitted
        self.row_used = row_used
        self.all_rows = bool(np.all(row_used))
        take = (lambda a: a) if self.all_rows else (lambda a: a[row_used])
        self.local = take(local_of_point[obs.point_index])
        self.normal = np.ascontiguousarray(take(obs.normal_cam))
        self.brightness = take(obs.brightness)
        self.log_cos_o = np.log(take(obs.cos_emission))
        self.n_rows = int(self.local.shape[0])
        # CSR layout of the Jacobian: 4 entries per row, columns already sorted.
        self._indptr = np.arange(0, 4 * self.n_rows + 1, 4, dtype=np.int64)
        self._indices = np.column_stack(
            [
                np.zeros(self.n_rows, np.int64),
                np.ones(self.n_rows, np.int64),
                2 + self.local,
                2 + self.n_fitted + self.local,
            ]
        ).ravel()

    # -- packing --------------------------------------------------------
    def pack(self, tangent, albedo_fitted, k_fitted) -> np.ndarray:
        return np.concatenate([np.asarray(tangent, float), np.asarray(albedo_fitted, float), np.asarray(k_fitted, float)])

    def unpack(self, x):
        m = self.n_fitted
        return x[:2], x[2 : 2 + m], x[2 + m :]

    # -- model ----------------------------------------------------------
    def _evaluate(self, x, with_jacobian):
        tangent, albedo, k = self.unpack(x)
        u_norm = np.sqrt(1.0 + tangent[0] ** 2 + tangent[1] ** 2)
        light = np.array([tangent[0], tangent[1], -1.0]) / u_norm
        cos_i_raw = self.normal @ light
        cos_i = np.maximum(cos_i_raw, self.cos_floor)
        log_cos_i = np.log(cos_i)
        k_row = k[self.local]
        with np.errstate(over="ignore"):  # a wild trial k may overflow: infinite cost, step rejected
            shape_term = minnaert_factor(k_row, log_cos_i, self.log_cos_o)  # cos_i^k cos_o^(k-1)
        model = albedo[self.local] * shape_term
        residual = model - self.brightness
        if not with_jacobian:
            return residual, None
        d_albedo = shape_term
        d_k = model * (log_cos_i + self.log_cos_o)
        # d model / d l = albedo k cos_i^(k-1) cos_o^(k-1) n; zero where the floor is active.
        d_light_scale = np.where(cos_i_raw > self.cos_floor, model * k_row / cos_i, 0.0)
        # d l / d a = (e_x - l l_x) / |u|, d l / d b = (e_y - l l_y) / |u|.
        dl_da = (np.array([1.0, 0.0, 0.0]) - light * light[0]) / u_norm
        dl_db = (np.array([0.0, 1.0, 0.0]) - light * light[1]) / u_norm
        d_a = d_light_scale * (self.normal @ dl_da)
        d_b = d_light_scale * (self.normal @ dl_db)
        return residual, (d_a, d_b, d_albedo, d_k)

    def residuals(self, x) -> np.ndarray:
        return self._evaluate(x, False)[0]

    def jacobian_columns(self, x):
        """The 4 non-zeros of each Jacobian row: d/da, d/db, d/d albedo_p, d/d k_p."""
        return self._evaluate(x, True)[1]

    def jacobian(self, x) -> scipy.sparse.csr_matrix:
        """Sparse Jacobian (n_rows, n_params) in CSR, built without loops."""
        data = np.column_stack(self.jacobian_columns(x)).ravel()
        return scipy.sparse.csr_matrix(
            (data, self._indices, self._indptr), shape=(self.n_rows, self.n_params), copy=False
        )

    def cost(self, x) -> float:
        residual = self.residuals(x)
        return 0.5 * float(residual @ residual)

    # -- result ---------------------------------------------------------
    def per_point(self, values_fitted) -> np.ndarray:
        out = np.full(self.obs.n_points, np.nan)
        out[self.fitted] = values_fitted
        return out


def initial_albedo_and_k(problem: KoizumiProblem, light_dir_cam):
    """Closed-form per-point albedo and k for a given light, all points at once.

    Taking logs of the Minnaert law gives a line per point,
    ``log b + log cos_o = log albedo + k (log cos_i + log cos_o)``; it is
    fitted by weighted least squares with weights ``b**2`` (so that the log
    residuals approximate brightness residuals), through 2x2 normal
    equations accumulated with ``np.bincount``. k is clipped to
    ``INIT_K_RANGE`` and the albedo refitted for the clipped k. Points whose
    system is singular (no spread in ``log cos_i + log cos_o``, or no
    positive brightness) get k = 1 and the mean albedo of the others.
    Observations with ``b <= 0`` or ``cos_i <= 0`` get zero weight.
    """
    light = np.asarray(light_dir_cam, dtype=np.float64)
    cos_i = problem.normal @ light
    usable = (problem.brightness > 0.0) & (cos_i > 0.0)
    weight = np.where(usable, problem.brightness**2, 0.0)
    log_cos_i = np.log(np.where(usable, cos_i, 1.0))
    log_b = np.log(np.where(usable, problem.brightness, 1.0))
    x = log_cos_i + problem.log_cos_o
    y = log_b + problem.log_cos_o

    m = problem.n_fitted
    sums = [np.bincount(problem.local, weights=w, minlength=m) for w in (weight, weight * x, weight * y)]
    s0, sx, sy = sums
    # Centre per point before forming second moments: avoids cancellation.
    with np.errstate(invalid="ignore", divide="ignore"):
        x_mean = np.where(s0 > 0, sx / s0, 0.0)
        y_mean = np.where(s0 > 0, sy / s0, 0.0)
    dx = x - x_mean[problem.local]
    dy = y - y_mean[problem.local]
    sxx = np.bincount(problem.local, weights=weight * dx * dx, minlength=m)
    sxy = np.bincount(problem.local, weights=weight * dx * dy, minlength=m)
    # Weighted variance of x per point; below this the slope is undetermined.
    with np.errstate(invalid="ignore", divide="ignore"):
        variance = np.where(s0 > 0, sxx / s0, 0.0)
        regular = (s0 > 0) & (variance > 1e-12)
        k = np.where(regular, sxy / np.where(regular, sxx, 1.0), 1.0)
    k = np.clip(k, *INIT_K_RANGE)
    log_albedo = y_mean - k * x_mean
    albedo = np.exp(log_albedo)
    fallback = float(np.mean(albedo[regular])) if np.any(regular) else 1.0
    albedo = np.where(regular, albedo, fallback)
    k = np.where(regular, k, 1.0)
    return albedo, k


def profile_cost(problem: KoizumiProblem, light_dir_cam) -> float:
    """Cost of a light direction with every point's albedo and k from :func:`initial_albedo_and_k`.

    A cheap stand-in for the joint cost minimised over the per-point
    parameters: one pass of closed-form fits, no iterations.
    """
    albedo, k = initial_albedo_and_k(problem, light_dir_cam)
    return problem.cost(problem.pack(tangent_from_light(light_dir_cam), albedo, k))


def search_light(
    problem: KoizumiProblem,
    light_guess,
    *,
    max_points: int = 500,
    half_width: float = 0.8,
    n_grid: int = 17,
    n_refine: int = 2,
) -> np.ndarray:
    """Coarse-to-fine grid search of the light by :func:`profile_cost`, for LM's start.

    :func:`~.light_search.grid_search` (where the reasons for a grid are)
    with the best node so far kept across levels, starting from
    ``light_guess``: tangent coordinates ``[-half_width, half_width]**2``
    with ``n_grid**2`` nodes, then ``n_refine`` finer 7x7 levels. Only
    ``max_points`` points (evenly spaced in index order) enter the search.
    """
    obs = problem.obs
    fitted_points = np.flatnonzero(problem.fitted)
    if fitted_points.size > max_points:
        chosen = np.zeros(obs.n_points, bool)
        chosen[evenly_spaced(fitted_points, max_points)] = True
        rows = chosen[obs.point_index]
        obs = Observations(
            obs.point_index[rows], obs.normal_cam[rows], obs.view_cam[rows], obs.brightness[rows], obs.n_points
        )
        problem = KoizumiProblem(obs, min_observations=1, cos_floor=problem.cos_floor)

    def score(tangents):  # a few hundred cheap evaluations, not a loop over points
        return np.array([profile_cost(problem, light_from_tangent(tangent)) for tangent in tangents])

    best = grid_search(
        score, tangent_from_light(light_guess), half_width=half_width, n_grid=n_grid, n_refine=n_refine, keep_best=True
    )
    return light_from_tangent(best)


def _initial_parameters(problem: KoizumiProblem, light_init):
    obs = problem.obs
    if light_init is None or (isinstance(light_init, str) and light_init == "iwano"):
        # Lambert guess (k = 1, one albedo) for the light: linear and cheap.
        guess = fit_iwano_linear(obs, 1.0).light_dir_cam
        light_init = search_light(problem, guess) if light_init is None else guess
    elif isinstance(light_init, str):
        raise ValueError(f"light_init must be None, 'iwano' or a (3,) vector, got {light_init!r}")
    light_init = np.asarray(light_init, dtype=np.float64)
    if light_init.shape != (3,) or not np.all(np.isfinite(light_init)):
        raise ValueError(f"light_init must be a finite (3,) vector, got {light_init!r}")
    light_init = light_init / np.linalg.norm(light_init)
    tangent = tangent_from_light(light_init)
    albedo, k = initial_albedo_and_k(problem, light_init)
    return problem.pack(tangent, albedo, k)


def _solve_least_squares(problem: KoizumiProblem, x0, ftol, xtol, gtol, max_nfev, verbose, lsmr_tol):
    """The generic path: scipy's trust-region reflective with a sparse Jacobian and LSMR."""
    result = scipy.optimize.least_squares(
        problem.residuals,
        x0,
        jac=problem.jacobian,
        method="trf",
        tr_solver="lsmr",
        tr_options={"atol": lsmr_tol, "btol": lsmr_tol},
        x_scale="jac",
        ftol=ftol,
        xtol=xtol,
        gtol=gtol,
        max_nfev=max_nfev,
        verbose=verbose,
    )
    return result.x, float(result.cost), int(result.njev or 0), int(result.nfev), bool(result.success), str(result.message)


def _solve_block_lm(problem: KoizumiProblem, x0, ftol, xtol, gtol, max_nfev, verbose, hold_light=False):
    """Levenberg-Marquardt exploiting the arrow structure of J^T J.

    Each residual depends on the two light parameters and on its own point's
    (albedo, k). The damped normal matrix is therefore a 2x2 light block V,
    2x2 point blocks U_p and 2x2 couplings W_p; eliminating the point blocks
    (Schur complement) leaves a 2x2 system for the light step, after which
    each point's step follows in closed form. One iteration costs a few
    passes over the observations; a damped re-solve after a rejected step
    costs O(n_points) plus one residual evaluation.

    Damping is Marquardt's ``lambda * D`` with D the running maximum of
    diag(J^T J) (MINPACK's scaling, like ``x_scale="jac"``); lambda follows
    Nielsen's gain-ratio rule. Stopping mirrors least_squares: ftol on the
    relative cost decrease, xtol on the step relative to ``|x|``, gtol on the
    scaled gradient, or ``max_nfev`` residual evaluations.

    ``hold_light``: the light stays at ``x0``'s; the couplings and the light's
    gradient are zeroed, so its step is exactly zero and each point's step is
    its own 2x2 solve.
    """
    local = problem.local
    m = problem.n_fitted
    x = x0.copy()
    tiny = np.finfo(float).tiny

    def bsum(weights):
        return np.bincount(local, weights=weights, minlength=m)

    residual, columns = problem._evaluate(x, True)
    cost = 0.5 * float(residual @ residual)
    nfev, n_iterations = 1, 0
    damping, nu = 1e-3, 2.0
    scale_light = np.full(2, tiny)
    scale_point = np.full((2, m), tiny)
    status = None  # (success, message) once stopped

    while status is None:
        d_a, d_b, d_rho, d_k = columns
        # Blocks of J^T J and J^T r.
        v_aa, v_ab, v_bb = float(d_a @ d_a), float(d_a @ d_b), float(d_b @ d_b)
        u_rr, u_rk, u_kk = bsum(d_rho * d_rho), bsum(d_rho * d_k), bsum(d_k * d_k)
        w_ar, w_ak, w_br, w_bk = bsum(d_a * d_rho), bsum(d_a * d_k), bsum(d_b * d_rho), bsum(d_b * d_k)
        g_a, g_b = float(d_a @ residual), float(d_b @ residual)
        g_r, g_k = bsum(d_rho * residual), bsum(d_k * residual)
        if hold_light:
            w_ar = w_ak = w_br = w_bk = np.zeros(m)
            g_a = g_b = 0.0
        gradient = np.concatenate([[g_a, g_b], g_r, g_k])

        scale_light = np.maximum(scale_light, [v_aa, v_bb])
        scale_point = np.maximum(scale_point, np.stack([u_rr, u_kk]))
        scale = np.concatenate([scale_light, scale_point[0], scale_point[1]])
        if cost == 0.0 or np.max(np.abs(gradient) / np.sqrt(scale)) < gtol:
            status = True, "gtol: the scaled gradient is below tolerance"
            break

        while True:  # raise the damping until a step lowers the cost
            step_light, step_albedo, step_k = solve_arrow_system(
                (v_aa + damping * scale_light[0], v_ab, v_bb + damping * scale_light[1]),
                (u_rr + damping * scale_point[0], u_rk, u_kk + damping * scale_point[1]),
                (w_ar, w_ak, w_br, w_bk),
                (g_a, g_b),
                (g_r, g_k),
            )
            step = np.concatenate([step_light, step_albedo, step_k])
            if not np.all(np.isfinite(step)):
                status = False, "the damped normal equations became singular"
                break

            x_new = x + step
            residual_new = problem.residuals(x_new)
            nfev += 1
            cost_new = 0.5 * float(residual_new @ residual_new)
            predicted = 0.5 * float(step @ (damping * scale * step - gradient))
            actual = cost - cost_new
            step_small = np.linalg.norm(step) <= xtol * (xtol + np.linalg.norm(x))
            if actual > 0.0 and predicted > 0.0:
                gain = actual / predicted
                x, residual, cost = x_new, residual_new, cost_new
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                if actual < ftol * (cost + actual):
                    status = True, "ftol: the relative reduction of the cost is below tolerance"
                elif step_small:
                    status = True, "xtol: the step is below tolerance"
                break
            damping *= nu
            nu *= 2.0
            if damping > 1e30:
                status = True, "the cost cannot be lowered further (machine precision)"
                break
            if step_small:
                status = True, "xtol: the step is below tolerance (no further decrease)"
                break
            if nfev >= max_nfev:
                break
        n_iterations += 1
        if verbose:
            print(f"block LM iteration {n_iterations}: cost {cost:.6e}, damping {damping:.2e}, nfev {nfev}")
        if status is None and nfev >= max_nfev:
            status = False, f"maximum number of function evaluations ({max_nfev}) reached"
        if status is None:
            residual, columns = problem._evaluate(x, True)
    success, message = status
    return x, cost, n_iterations, nfev, success, message



SOLVERS = ("block_lm", "least_squares")


def fit_koizumi_lm(
    obs: Observations,
    light_init=None,
    *,
    solver: str = "block_lm",
    ftol: float = 1e-14,
    xtol: float = 1e-14,
    gtol: float = 1e-14,
    max_nfev: int | None = None,
    min_observations: int = 2,
    lsmr_tol: float = 1e-10,
    verbose: int = 0,
    hold_light: bool = False,
) -> FitResult:
    """The paper's estimator: one global light, an albedo and a Minnaert k per point.

    Minimises ``sum_j (b_j - albedo_p cos_i_j**k_p cos_o_j**(k_p - 1))**2``
    over the light's tangent coordinates (:func:`light_from_tangent`) and every
    fitted point's albedo and k, jointly.

    Parameters
    ----------
    obs : Observations
        Observations must be lit at the truth (``cos_i > 0``; ``observe``
        keeps ``cos_i > min_cos_incidence``). Inside the residual ``cos_i`` is
        floored at ``COS_INCIDENCE_FLOOR`` so a trial step never breaks log/pow.
    light_init : None, "iwano" or (3,) array
        Starting light. ``None`` (default): Iwano's linear fit with k = 1 (a
        Lambert guess), then :func:`search_light`, a coarse-to-fine grid
        search of the profile cost that guards against Iwano's bias when the
        albedo varies. ``"iwano"``: the Lambert guess alone. A (3,) vector:
        that light (camera frame, ``l_z < 0``). Per-point albedo and k always
        start from the closed-form log-linear fit (:func:`initial_albedo_and_k`).
    solver : {"block_lm", "least_squares"}
        ``"block_lm"`` (default): Levenberg-Marquardt written here that
        solves each step exactly through the arrow structure of J^T J (per
        point 2x2 blocks, Schur complement on the 2x2 light block).
        ``"least_squares"``: ``scipy.optimize.least_squares(method="trf",
        tr_solver="lsmr", x_scale="jac")`` with the analytic sparse Jacobian;
        kept as an independent check. Measured on 50,000 points x 20
        observations, noiseless, 2 cores: block_lm 0.4-0.9 s, least_squares
        2-10 s, both recovering light, albedo and k to ~1e-15. With noise
        (sigma 0.005) the two agree to ~5e-9 and block_lm ends nearer the
        optimum (scaled gradient 1e-11 against 4e-9), LSMR being inexact.
    ftol, xtol, gtol, max_nfev
        Stopping rules with least_squares' meaning. ``max_nfev`` defaults to
        200 for block_lm and 100 * n_params capped at 2000 for least_squares.
    min_observations : int
        Points with fewer observations are not fitted (NaN): one observation
        cannot separate albedo from k.
    lsmr_tol : float
        ``atol``/``btol`` of LSMR in the least_squares path. scipy's default,
        1e-6, is enough on noiseless data but on noisy data its inexact steps
        make trf crawl (50,000 points, sigma 0.005: 845 evaluations, 320 s,
        light still 1.5e-5 deg off the optimum); 1e-10 converges in about 10.
    hold_light : bool
        Keep the light at ``light_init`` (a vector) and fit only each point's
        albedo and k under it (block_lm only): the second step of a two-step
        estimate whose light comes from elsewhere (:func:`fit_pooled_k`).
    """
    start = time.perf_counter()
    if hold_light and (solver != "block_lm" or light_init is None or isinstance(light_init, str)):
        raise ValueError("fit_koizumi_lm: hold_light needs solver='block_lm' and a (3,) light_init vector")
    if solver not in SOLVERS:
        raise ValueError(f"fit_koizumi_lm: solver must be one of {SOLVERS}, got {solver!r}")
    problem = KoizumiProblem(obs, min_observations=min_observations)
    if problem.n_fitted == 0 or problem.n_rows < problem.n_params:
        raise ValueError(
            f"fit_koizumi_lm: {problem.n_rows} usable observations of {problem.n_fitted} points "
            f"cannot determine {problem.n_params} unknowns"
        )
    x0 = _initial_parameters(problem, light_init)
    if solver == "block_lm":
        max_nfev = 200 if max_nfev is None else int(max_nfev)
        x, cost, n_iterations, nfev, success, message = _solve_block_lm(
            problem, x0, ftol, xtol, gtol, max_nfev, verbose, hold_light
        )
        solver_name = "block-Schur Levenberg-Marquardt (numpy)"
    else:
        max_nfev = min(100 * problem.n_params, 2000) if max_nfev is None else int(max_nfev)
        x, cost, n_iterations, nfev, success, message = _solve_least_squares(
            problem, x0, ftol, xtol, gtol, max_nfev, verbose, lsmr_tol
        )
        solver_name = "scipy.optimize.least_squares trf/lsmr, sparse analytic Jacobian"
    tangent, albedo, k = problem.unpack(x)
    elapsed = time.perf_counter() - start
    return FitResult(
        method="koizumi_lm",
        light_dir_cam=light_from_tangent(tangent),
        albedo=problem.per_point(albedo),
        minnaert_k=problem.per_point(k),
        n_points_fitted=problem.n_fitted,
        n_obs=problem.n_rows,
        cost=cost,
        n_iterations=n_iterations,
        nfev=nfev,
        success=success,
        message=message,
        fit_seconds=elapsed,
        solver=solver_name,
    )


def fit_pooled_k(obs: Observations, light_init, minnaert_k_init: float, *, min_observations: int = 2, ftol: float = 1e-12, xtol: float = 1e-12, max_nfev: int = 200) -> FitResult:
    """One light, an albedo per point and one Minnaert k for the whole body.

    The paper's model with k pooled over the points, as planetary photometry
    fits a Minnaert k to a region. It is the light step of the refinement
    (``refine``): with a free k per point the light's direction out of the
    plane of the views and the Sun is nearly a gauge freedom. A brightness
    offset ``c`` common to a point's views (what a tilt of the light out of
    that plane adds to ``cos_i`` at a point of latitude ``lat``: ``c = e
    tan(lat)``) changes ``log b`` by ``c / cos_i``, which is ``c`` (taken up
    by the albedo) plus ``-c log cos_i`` (taken up by a per-point k) to
    second order in the phase of the view. A per-point k therefore lets
    errors of 1e-3 in the samples move the light by a degree; one k for the
    body does not.

    Minimises ``sum_j (b_j - albedo_p cos_i_j**k cos_o_j**(k - 1))**2`` with
    ``scipy.optimize.least_squares`` (trf, analytic sparse Jacobian). Points
    with fewer than ``min_observations`` rows are left out (NaN).
    """
    start = time.perf_counter()
    problem = KoizumiProblem(obs, min_observations=min_observations)
    m = problem.n_fitted
    if m == 0 or problem.n_rows < m + 3:
        raise ValueError(f"fit_pooled_k: {problem.n_rows} usable observations of {m} points cannot determine {m + 3} unknowns")
    light_init = np.asarray(light_init, dtype=np.float64)
    if light_init.shape != (3,) or not np.all(np.isfinite(light_init)):
        raise ValueError(f"fit_pooled_k: light_init must be a finite (3,) vector, got {light_init!r}")
    if not np.isfinite(minnaert_k_init) or minnaert_k_init <= 0:
        raise ValueError(f"fit_pooled_k: minnaert_k_init must be a positive number, got {minnaert_k_init!r}")
    light_init = light_init / np.linalg.norm(light_init)
    # Start: each point's albedo by least squares under the initial light and k (the Minnaert law in a
    # mixed power/log form of its own; laws.minnaert_factor would change its last bits).
    shape_term = np.maximum(problem.normal @ light_init, problem.cos_floor) ** minnaert_k_init * np.exp((minnaert_k_init - 1.0) * problem.log_cos_o)
    albedo0 = np.bincount(problem.local, shape_term * problem.brightness, m) / np.bincount(problem.local, shape_term**2, m)
    x0 = np.concatenate([tangent_from_light(light_init), albedo0, [minnaert_k_init]])

    def expand(x):
        return problem.pack(x[:2], x[2:-1], np.full(m, x[-1]))

    # The problem's CSR layout, with every row's k entry in the one k column.
    indices = problem._indices.copy()
    indices[3::4] = 2 + m

    def jacobian(x):
        data = np.column_stack(problem.jacobian_columns(expand(x))).ravel()
        return scipy.sparse.csr_matrix((data, indices, problem._indptr), shape=(problem.n_rows, m + 3))

    solution = scipy.optimize.least_squares(
        lambda x: problem.residuals(expand(x)), x0, jac=jacobian, method="trf", x_scale="jac", ftol=ftol, xtol=xtol, gtol=1e-14, max_nfev=max_nfev,
    )
    tangent, albedo, k = problem.unpack(expand(solution.x))
    return FitResult(
        method="pooled_k",
        light_dir_cam=light_from_tangent(tangent),
        albedo=problem.per_point(albedo),
        minnaert_k=problem.per_point(k),
        n_points_fitted=m,
        n_obs=problem.n_rows,
        cost=float(solution.cost),
        n_iterations=int(solution.njev or 0),
        nfev=int(solution.nfev),
        success=bool(solution.success),
        message=str(solution.message),
        fit_seconds=time.perf_counter() - start,
        solver="scipy.optimize.least_squares trf, sparse analytic Jacobian, one k",
    )
