"""The light and a photometric law's parameters fitted to brightness observations, for every law.

The forward model of every law of ``reflectance.laws`` behind one fit: the light
direction (``core``'s tangent chart about ``-z``) and the law's
parameters, each either fitted per point, fitted once for the body
(global), or held at a given value. A ``FitSpec`` says which. Residuals are
``(law - b) / sigma``; the Jacobian is the law's central-difference one
(``PhotometricModel.jacobian``), the light entering through ``cos_i`` and
``cos_g``. The normal matrix is an arrow (the globals, then one small block
per point), so Levenberg-Marquardt eliminates the point blocks (Schur
complement) and solves a system the size of the globals: the same scheme as
``koizumi``'s block LM, for any number of parameters.

The same blocks at the true parameters are the Fisher information
(:func:`fisher_information`): how well each parameter can be estimated
from these observations, per point and globally, the evidence for which
parameters a fit frees per point and which it holds global.

:func:`fit_law_to_law` fits one law to another directly over given
incidence, emission and phase samples (no images): the same fit, with the
brightness computed from the target law instead of read from images.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from asteroid_photometry.estimation.core import (
    angle_between_deg,
    light_from_tangent,
    light_std_deg,
    Observations,
    tangent_from_light,
)
from asteroid_photometry.reflectance import laws as photometry

__all__ = ["FitSpec", "ModelFit", "fit_model", "fisher_information", "fit_law_to_law", "bic"]

# Where a fitted parameter starts when the spec gives no start: typical values.
DEFAULT_START = {"albedo": 0.5, "lunar_l": 0.5, "minnaert_k": 0.8, "w": 0.5, "roughness_deg": 15.0, "hg_b": 0.3, "hg_c": 0.5, "b0": 1.0, "h": 0.05}
# Parameters that scale the law linearly: a point's start is solved in closed form.
LINEAR_SCALE = {"albedo"}
EXTRAPOLATIONS = 3


@dataclasses.dataclass(frozen=True)
class FitSpec:
    """Which parameters of ``model`` are fitted per point, which globally, and the values of the rest.

    ``fixed`` holds every parameter that is neither (and the law's options);
    ``start`` optional starting values of fitted ones; ``fit_light`` False
    holds the light at the start given to :func:`fit_model`.
    """

    model: str
    per_point: tuple = ()
    global_: tuple = ()
    fixed: dict = dataclasses.field(default_factory=dict)
    start: dict = dataclasses.field(default_factory=dict)
    fit_light: bool = True

    def __post_init__(self):
        law = photometry.get_model(self.model)
        named = list(self.per_point) + list(self.global_) + [name for name in self.fixed if name not in law.options]
        missing = [name for name in law.parameters if name not in named]
        extra = [name for name in named if name not in law.parameters]
        twice = {name for name in named if named.count(name) > 1}
        if missing or extra or twice:
            raise ValueError(
                f"fit of {self.model!r}: every parameter of {law.parameters} must be per_point, global or fixed exactly once"
                + (f"; not placed: {missing}" if missing else "") + (f"; unknown: {extra}" if extra else "")
                + (f"; placed twice: {sorted(twice)}" if twice else "")
            )

    @property
    def law(self) -> photometry.PhotometricModel:
        return photometry.get_model(self.model)

    @classmethod
    def from_config(cls, model: str, entry: dict, truth: dict | None = None, fit_light: bool = True) -> "FitSpec":
        """From a config entry ``{per_point: [...], global: [...]}``; the rest fixed at ``truth`` (or the entry's ``fixed``)."""
        law = photometry.get_model(model)
        per_point, global_ = tuple(entry.get("per_point", ())), tuple(entry.get("global", ()))
        values = {**(truth or {}), **entry.get("fixed", {})}
        fixed = {name: values[name] for name in (*law.parameters, *law.options) if name in values and name not in per_point + global_}
        return cls(model, per_point, global_, fixed, dict(entry.get("start", {})), fit_light)

    def n_parameters(self, n_points: int) -> int:
        return (2 if self.fit_light else 0) + len(self.global_) + n_points * len(self.per_point)


@dataclasses.dataclass
class ModelFit:
    """A fit's result: the light, the parameters (per point (n_points,) with NaN where unfitted; global floats)."""

    spec: FitSpec
    light_dir_cam: np.ndarray
    per_point: dict
    global_: dict
    fitted_points: np.ndarray
    residual_rms: float
    n_observations: int
    n_parameters: int
    cost: float
    n_iterations: int
    success: bool
    message: str
    fit_seconds: float

    @property
    def bic(self) -> float:
        return bic(self.cost, self.n_observations, self.n_parameters)

    def parameter_summary(self) -> dict:
        """Global values as they are; per-point ones by their median over the fitted points."""
        summary = dict(self.global_)
        for name, values in self.per_point.items():
            summary[name] = float(np.median(values[self.fitted_points]))
        return summary


def bic(cost: float, n_observations: int, n_parameters: int, known_variance: bool = False) -> float:
    """Bayesian information criterion of a least-squares fit with ``cost = sum(r^2) / 2``.

    With ``known_variance`` the residuals are already in units of their
    standard deviation: ``chi^2 + p ln n``; otherwise the variance is
    estimated too: ``n ln(RSS / n) + p ln n``.
    """
    rss = 2.0 * cost
    if known_variance:
        return float(rss + n_parameters * np.log(n_observations))
    return float(n_observations * np.log(max(rss, 1e-300) / n_observations) + n_parameters * np.log(n_observations))


class _Problem:
    """Rows of the fitted points, the packing of the parameter vector, residuals and Jacobian blocks."""

    def __init__(self, obs: Observations, spec: FitSpec, sigma=None, min_observations: int = 2):
        self.spec, self.law = spec, spec.law
        counts = np.bincount(obs.point_index, minlength=obs.n_points)
        self.fitted_points = counts >= max(min_observations, len(spec.per_point) + 1)
        rows = self.fitted_points[obs.point_index]
        local_of_point = np.cumsum(self.fitted_points) - 1
        self.local = local_of_point[obs.point_index[rows]]
        self.m = int(self.fitted_points.sum())
        self.normal = obs.normal_cam[rows]
        self.view = obs.view_cam[rows]
        self.cos_o = np.einsum("ij,ij->i", self.normal, self.view)
        self.brightness = obs.brightness[rows]
        self.weight = np.ones(len(self.brightness)) if sigma is None else 1.0 / np.asarray(sigma, dtype=np.float64)[rows]
        self.n_globals = (2 if spec.fit_light else 0) + len(spec.global_)
        self.n_local = len(spec.per_point)

    def params_of(self, light_tangent, global_values, point_values):
        params = dict(self.spec.fixed)
        params.update(zip(self.spec.global_, global_values))
        for j, name in enumerate(self.spec.per_point):
            params[name] = point_values[self.local, j]
        return params

    def evaluate(self, light_tangent, global_values, point_values, with_jacobian=True):
        light = light_from_tangent(light_tangent)
        cos_i = self.normal @ light
        cos_g = self.view @ light
        params = self.params_of(light_tangent, global_values, point_values)
        names = []
        if with_jacobian:
            names = (["cos_i", "cos_g"] if self.spec.fit_light else []) + list(self.spec.global_) + list(self.spec.per_point)
        model, derivatives = self.law.jacobian(params, cos_i, self.cos_o, cos_g, names)
        residual = (model - self.brightness) * self.weight
        if not with_jacobian:
            return residual, None, None
        n = len(residual)
        global_columns = np.empty((n, self.n_globals))
        column = 0
        if self.spec.fit_light:
            u_norm = np.sqrt(1.0 + light_tangent[0] ** 2 + light_tangent[1] ** 2)
            for axis in (0, 1):
                unit = np.zeros(3)
                unit[axis] = 1.0
                dl = (unit - light * light[axis]) / u_norm
                global_columns[:, column] = derivatives["cos_i"] * (self.normal @ dl) + derivatives["cos_g"] * (self.view @ dl)
                column += 1
        for name in self.spec.global_:
            global_columns[:, column] = derivatives[name]
            column += 1
        local_columns = np.column_stack([derivatives[name] for name in self.spec.per_point]) if self.n_local else np.empty((n, 0))
        return residual, global_columns * self.weight[:, None], local_columns * self.weight[:, None]

    def normal_blocks(self, residual, global_columns, local_columns):
        """``J^T J`` as (V (G,G), U (m,P,P), W (m,G,P)) and ``J^T r`` as (g_global (G,), g_local (m,P))."""
        m, n_local = self.m, self.n_local
        V = global_columns.T @ global_columns
        g_global = global_columns.T @ residual
        U = np.zeros((m, n_local, n_local))
        W = np.zeros((m, self.n_globals, n_local))
        g_local = np.zeros((m, n_local))
        for a in range(n_local):
            g_local[:, a] = np.bincount(self.local, weights=local_columns[:, a] * residual, minlength=m)
            for b in range(a, n_local):
                U[:, a, b] = U[:, b, a] = np.bincount(self.local, weights=local_columns[:, a] * local_columns[:, b], minlength=m)
            for c in range(self.n_globals):
                W[:, c, a] = np.bincount(self.local, weights=global_columns[:, c] * local_columns[:, a], minlength=m)
        return V, U, W, g_global, g_local


def _solve_arrow(V, U, W, g_global, g_local):
    """Solve ``[[V, W], [W^T, U]] [d_g; d_p] = -[g_g; g_p]`` through the Schur complement of the point blocks."""
    n_local = U.shape[1]
    if n_local:
        U_inv = np.linalg.inv(U)
        Y = np.einsum("mgp,mpq->mgq", W, U_inv)  # W U^-1
        S = V - np.einsum("mgq,mhq->gh", Y, W)
        rhs = -g_global + np.einsum("mgq,mq->g", Y, g_local)
    else:
        U_inv, Y, S, rhs = None, None, V, -g_global
    step_global = np.linalg.solve(S, rhs) if len(V) else np.zeros(0)
    if not n_local:
        return step_global, np.zeros((len(U), 0))
    q = -g_local - np.einsum("mgp,g->mp", W, step_global)
    return step_global, np.einsum("mpq,mq->mp", U_inv, q)


def _start(problem: _Problem, light_dir_start, n_points):
    spec = problem.spec
    tangent = tangent_from_light(light_dir_start)
    global_values = np.array([spec.start.get(name, DEFAULT_START[name]) for name in spec.global_], dtype=np.float64)
    point_values = np.zeros((problem.m, problem.n_local))
    for j, name in enumerate(spec.per_point):
        start = spec.start.get(name, DEFAULT_START[name])
        point_values[:, j] = np.asarray(start)[problem.fitted_points] if np.ndim(start) else start
    # A linear scale (albedo) starts at its least-squares value for the other starts.
    for j, name in enumerate(spec.per_point):
        if name in LINEAR_SCALE and name not in spec.start:
            unit = point_values.copy()
            unit[:, j] = 1.0
            residual, _, _ = problem.evaluate(tangent, global_values, unit, with_jacobian=False)
            shape = residual / problem.weight + problem.brightness
            numerator = np.bincount(problem.local, weights=(problem.weight * shape) * (problem.weight * problem.brightness), minlength=problem.m)
            denominator = np.bincount(problem.local, weights=(problem.weight * shape) ** 2, minlength=problem.m)
            point_values[:, j] = np.where(denominator > 0, numerator / np.maximum(denominator, 1e-300), start)
    return tangent, global_values, point_values


def _clamp(spec: FitSpec, global_values, point_values):
    """Keep trial values inside each parameter's valid range (a step may overshoot)."""
    ranges = spec.law.ranges
    for j, name in enumerate(spec.global_):
        global_values[j] = np.clip(global_values[j], *ranges[name])
    for j, name in enumerate(spec.per_point):
        point_values[:, j] = np.clip(point_values[:, j], *ranges[name])
    return global_values, point_values


def fit_model(obs: Observations, spec: FitSpec, light_dir_start, sigma=None, *, ftol=1e-12, xtol=1e-10, max_iterations=300, min_observations: int = 2) -> ModelFit:
    """Levenberg-Marquardt fit of ``spec``'s law to ``obs`` (see module docstring); ``sigma`` per observation weights it.

    With global parameters and a free light the fit goes in two stages: the
    parameters first under the starting light, then everything from there.
    A light several degrees off (the Minnaert start on a Hapke surface: 6.5
    deg at phase 0) otherwise drives Hapke's roughness to 0, where its
    derivative vanishes and the fit stays.
    """
    if spec.fit_light and spec.global_:
        started = time.perf_counter()
        first = fit_model(obs, dataclasses.replace(spec, fit_light=False), light_dir_start, sigma, ftol=ftol, xtol=xtol, max_iterations=max_iterations, min_observations=min_observations)
        starts = {**spec.start, **first.global_, **{name: values for name, values in first.per_point.items()}}
        second = _fit_stage(obs, dataclasses.replace(spec, start=starts), light_dir_start, sigma, ftol, xtol, max_iterations, min_observations)
        second.n_iterations += first.n_iterations
        second.fit_seconds = time.perf_counter() - started
        return second
    return _fit_stage(obs, spec, light_dir_start, sigma, ftol, xtol, max_iterations, min_observations)


def _fit_stage(obs, spec, light_dir_start, sigma, ftol, xtol, max_iterations, min_observations) -> ModelFit:
    started = time.perf_counter()
    problem = _Problem(obs, spec, sigma, min_observations)
    if problem.m == 0:
        raise ValueError(f"fit of {spec.model!r}: no point has enough observations ({min_observations})")
    tangent, global_values, point_values = _start(problem, light_dir_start, obs.n_points)
    n_light = 2 if spec.fit_light else 0

    def split(globals_vector):
        return (globals_vector[:2] if spec.fit_light else tangent_fixed), globals_vector[n_light:]

    tangent_fixed = tangent
    x_global = np.concatenate([tangent if spec.fit_light else np.zeros(0), global_values])
    residual, Jg, Jl = problem.evaluate(*split(x_global), point_values)
    cost = 0.5 * float(residual @ residual)
    damping, nu = 1e-3, 2.0
    scale_global = np.full(problem.n_globals, 1e-300)
    scale_local = np.full((problem.m, problem.n_local), 1e-300)
    success, message, iteration = False, f"maximum number of iterations ({max_iterations}) reached", 0
    for iteration in range(1, max_iterations + 1):
        V, U, W, g_global, g_local = problem.normal_blocks(residual, Jg, Jl)
        scale_global = np.maximum(scale_global, np.diag(V))
        scale_local = np.maximum(scale_local, np.einsum("mpp->mp", U))
        if cost == 0.0:
            success, message = True, "exact fit"
            break
        accepted = False
        while True:
            V_damped = V + np.diag(damping * scale_global)
            U_damped = U.copy()
            U_damped[:, np.arange(problem.n_local), np.arange(problem.n_local)] += damping * scale_local
            with np.errstate(all="ignore"):
                try:
                    step_global, step_local = _solve_arrow(V_damped, U_damped, W, g_global, g_local)
                except np.linalg.LinAlgError:
                    step_global = np.full(problem.n_globals, np.nan)
                    step_local = np.zeros_like(point_values)
            if not (np.all(np.isfinite(step_global)) and np.all(np.isfinite(step_local))):
                damping *= 10.0
                if damping > 1e30:
                    break
                continue
            new_global, new_local = x_global + step_global, point_values + step_local
            new_global[n_light:], new_local = _clamp(spec, new_global[n_light:], new_local)
            new_residual, _, _ = problem.evaluate(*split(new_global), new_local, with_jacobian=False)
            new_cost = 0.5 * float(new_residual @ new_residual)
            step = np.concatenate([step_global, step_local.ravel()])
            gradient = np.concatenate([g_global, g_local.ravel()])
            predicted = 0.5 * float(step @ (np.concatenate([damping * scale_global, (damping * scale_local).ravel()]) * step - gradient))
            actual = cost - new_cost
            if np.isfinite(new_cost) and actual > 0.0 and predicted > 0.0:
                gain = actual / predicted
                # Where the law has a cusp (Hapke's roughness at psi = 0) the
                # Gauss-Newton steps fall short by a steady factor: try longer ones.
                for _ in range(EXTRAPOLATIONS):
                    longer_global, longer_local = x_global + 2.0 * (new_global - x_global), point_values + 2.0 * (new_local - point_values)
                    longer_global[n_light:], longer_local = _clamp(spec, longer_global[n_light:], longer_local)
                    longer_residual, _, _ = problem.evaluate(*split(longer_global), longer_local, with_jacobian=False)
                    longer_cost = 0.5 * float(longer_residual @ longer_residual)
                    if not longer_cost < new_cost:
                        break
                    new_global, new_local, new_cost = longer_global, longer_local, longer_cost
                    step_global, step_local = new_global - x_global, new_local - point_values
                    step = np.concatenate([step_global, step_local.ravel()])
                actual = cost - new_cost
                damping *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                accepted = True
                break
            damping *= nu
            nu *= 2.0
            if damping > 1e30:
                break
        if not accepted:
            success, message = True, "the cost cannot be lowered further"
            break
        x_norm = np.linalg.norm(np.concatenate([x_global, point_values.ravel()]))
        small_step = np.linalg.norm(step) <= xtol * (xtol + x_norm)
        x_global, point_values, previous_cost = new_global, new_local, cost
        residual, Jg, Jl = problem.evaluate(*split(x_global), point_values)
        cost = 0.5 * float(residual @ residual)
        if actual < ftol * previous_cost:
            success, message = True, "ftol: the relative reduction of the cost is below tolerance"
            break
        if small_step:
            success, message = True, "xtol: the step is below tolerance"
            break

    light_tangent, global_values = split(x_global)
    per_point = {}
    for j, name in enumerate(spec.per_point):
        values = np.full(obs.n_points, np.nan)
        values[problem.fitted_points] = point_values[:, j]
        per_point[name] = values
    n_rows = len(residual)
    return ModelFit(
        spec=spec,
        light_dir_cam=light_from_tangent(light_tangent),
        per_point=per_point,
        global_={name: float(value) for name, value in zip(spec.global_, global_values)},
        fitted_points=problem.fitted_points,
        residual_rms=float(np.sqrt(np.mean((residual / problem.weight) ** 2))),
        n_observations=n_rows,
        n_parameters=spec.n_parameters(problem.m),
        cost=cost,
        n_iterations=iteration,
        success=success,
        message=message,
        fit_seconds=time.perf_counter() - started,
    )


def fisher_information(obs: Observations, spec: FitSpec, light_dir_cam, truth: dict, sigma) -> dict:
    """Cramer-Rao standard deviations of ``spec``'s fitted parameters at the truth, for noise ``sigma``.

    ``truth`` holds the law's true parameters (scalars: a uniform surface).
    Returns ``light_std_deg`` and, per fitted parameter, ``{name}_std``: a
    global one's, or the median over points of a per-point one's (marginal,
    the light's and the globals' uncertainty included); and
    ``condition``, the condition number of the globals' Schur complement
    (infinite: some global combination is not identifiable).
    """
    spec = dataclasses.replace(spec, fixed={**spec.fixed, **{name: truth[name] for name in spec.fixed if name in truth}})
    problem = _Problem(obs, spec, np.broadcast_to(np.asarray(sigma, dtype=np.float64), obs.brightness.shape))
    global_values = np.array([truth[name] for name in spec.global_], dtype=np.float64)
    point_values = np.column_stack([np.full(problem.m, truth[name]) for name in spec.per_point]) if spec.per_point else np.zeros((problem.m, 0))
    tangent = tangent_from_light(light_dir_cam)
    _, Jg, Jl = problem.evaluate(tangent, global_values, point_values)
    V, U, W, _, _ = problem.normal_blocks(np.zeros(len(Jg)), Jg, Jl)
    with np.errstate(all="ignore"):
        if problem.n_local:
            U_inv = np.linalg.inv(U)
            Y = np.einsum("mgp,mpq->mgq", W, U_inv)
            S = V - np.einsum("mgq,mhq->gh", Y, W)
        else:
            U_inv, Y, S = None, None, V
        singular = np.linalg.svd(S, compute_uv=False) if len(S) else np.ones(1)
        condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else float("inf")
        S_inv = np.linalg.pinv(S) if len(S) else S
        result = {"condition": condition}
        n_light = 2 if spec.fit_light else 0
        if spec.fit_light:
            result["light_std_deg"] = light_std_deg(tangent, S_inv[:2, :2])
        for j, name in enumerate(spec.global_):
            result[f"{name}_std"] = float(np.sqrt(max(S_inv[n_light + j, n_light + j], 0.0)))
        if problem.n_local:
            # Marginal covariance of each point: U^-1 + Y^T S^-1 Y.
            marginal = U_inv + np.einsum("mgp,gh,mhq->mpq", Y, S_inv, Y)
            for j, name in enumerate(spec.per_point):
                result[f"{name}_std"] = float(np.median(np.sqrt(np.maximum(marginal[:, j, j], 0.0))))
    return result


def fit_law_to_law(target_model: str, target_params: dict, spec: FitSpec, normal_cam, view_cam, point_index, n_points, light_dir_cam, light_dir_start=None) -> ModelFit:
    """Fit ``spec`` to the brightness that ``target_model`` gives at these samples, without images.

    The samples are the observation geometry (unit normals and view vectors
    in the camera frame, with the point of each); the target's brightness is
    its law at the true light ``light_dir_cam``. The fit starts from
    ``light_dir_start`` (default: the truth) and frees the light when the
    spec says so.
    """
    from asteroid_photometry.reflectance.laws import geometry_cosines

    light = np.asarray(light_dir_cam, dtype=np.float64)
    cos_i, cos_o, cos_g = geometry_cosines(normal_cam, light, view_cam)
    brightness = photometry.get_model(target_model).radiance_factor(target_params, cos_i, cos_o, cos_g)
    obs = Observations(point_index=point_index, normal_cam=normal_cam, view_cam=view_cam, brightness=brightness, n_points=int(n_points))
    return fit_model(obs, spec, light if light_dir_start is None else light_dir_start)


def light_error_deg(fit: ModelFit, light_dir_true) -> float:
    return float(angle_between_deg(fit.light_dir_cam, light_dir_true))
