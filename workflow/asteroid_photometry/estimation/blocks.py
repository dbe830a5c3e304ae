"""The observations regrouped for streamed passes, and the brightness pass both varpro and fisher make.

:class:`PointBlocks` regroups the rows of the fitted points into dense
(points x observations) blocks, one per observation count, walked in
cache-sized chunks; :func:`joint_pass` is one pass over them that assembles
the arrow-structured normal equations ``J^T W J`` and the gradient ``J^T W
r`` of the brightness residuals ``albedo cos_i**k cos_o**(k - 1) - b``
(with an IRLS weight for a robust :class:`Loss`).
:func:`brightness_normal_equations` is that pass with plain ``1 / sigma**2``
weights: ``varpro``'s Gauss-Newton steps and ``fisher``'s information
matrix are both made of it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from asteroid_photometry.estimation.core import COS_INCIDENCE_FLOOR, Observations

__all__ = [
    "CHUNK_ROWS",
    "DEFAULT_F_SCALE",
    "HUBER",
    "LOSSES",
    "Loss",
    "PassSums",
    "PointBlocks",
    "brightness_normal_equations",
    "chunk_geometry",
    "joint_pass",
    "light_frame",
]

LOSSES = ("linear", "huber", "cauchy")
# Default loss thresholds, in units of the standardized residual: the usual
# constants giving 95 % efficiency under Gaussian noise.
DEFAULT_F_SCALE = {"linear": np.inf, "huber": 1.345, "cauchy": 2.3849}
# Rows per chunk of a streamed pass: 64k rows keep a chunk's ~20 temporaries in cache.
CHUNK_ROWS = 1 << 16
# MAD of a standard normal: sigma = MAD_TO_SIGMA * median(|z|).
MAD_TO_SIGMA = 1.482602218505602


# --------------------------------------------------------------------------
# Layout: rows regrouped into dense (points x observations) blocks
# --------------------------------------------------------------------------


@dataclasses.dataclass
class _Block:
    count: int  # observations per point in this block
    offset: int  # first slot of the block's points in the flat per-point arrays
    rows: np.ndarray  # (n, count) row indices into the Observations
    normal: np.ndarray  # (3, n * count) unit normals, component-major (camera frame)
    log_cos_o: np.ndarray  # (n, count)
    brightness: np.ndarray  # (n, count)
    inv_var: np.ndarray | None  # (n, count) 1 / sigma**2, or None for the layout's scalar
    keep: np.ndarray | None = None  # (n, count) 1.0 kept / 0.0 rejected, None: all kept

    @property
    def n(self) -> int:
        return self.rows.shape[0]


@dataclasses.dataclass
class _Chunk:
    block: _Block
    points: slice  # slice of the flat per-point arrays
    p0: int
    p1: int

    @property
    def shape(self):
        return self.p1 - self.p0, self.block.count

    @property
    def normal(self):
        count = self.block.count
        return self.block.normal[:, self.p0 * count : self.p1 * count]

    def rows_of(self, name):
        array = getattr(self.block, name)
        return None if array is None else array[self.p0 : self.p1]


class PointBlocks:
    """The rows of the fitted points, regrouped for streamed passes.

    Points with at least ``min_observations`` rows (and, if ``points`` is
    given, only those; :meth:`subset` cuts a smaller layout from this one) are grouped by their number of observations ``c``;
    each group is a dense block of shape (points, c), so a per-point value
    broadcasts along axis 1 and a per-point sum is a sum along it. The flat
    per-point arrays of the solvers list the points block by block
    (``point_ids`` gives their indices in the Observations). Works for rows
    in any order; rows sorted by point (as ``observe`` and
    ``synthetic_observations`` write them) avoid a sort.

    ``inv_var`` is ``1 / sigma**2`` per observation: a scalar or an (n_obs,)
    array in the Observations' row order.
    """

    def __init__(self, obs: Observations, *, min_observations=2, points=None, inv_var=1.0, chunk_rows=CHUNK_ROWS):
        counts = obs.observations_per_point
        eligible = counts >= max(int(min_observations), 1)
        if points is not None:
            chosen = np.zeros(obs.n_points, bool)
            chosen[np.asarray(points, dtype=np.int64)] = True
            eligible &= chosen
        point_index = obs.point_index
        order = None
        if obs.n_obs > 1 and not bool(np.all(point_index[1:] >= point_index[:-1])):
            order = np.argsort(point_index, kind="stable")
        starts = np.cumsum(counts) - counts
        per_row_inv_var = np.ndim(inv_var) > 0
        self.inv_var = 1.0 if per_row_inv_var else float(inv_var)
        self.n_points_total = obs.n_points
        self.chunk_rows = int(chunk_rows)
        cos_emission = obs.cos_emission
        self.blocks: list[_Block] = []
        point_ids = []
        for count in np.unique(counts[eligible]):
            count = int(count)
            ids = np.flatnonzero(eligible & (counts == count))
            rows = starts[ids, None] + np.arange(count)
            if order is not None:
                rows = order[rows]
            flat_rows = rows.ravel()
            normal = np.empty((3, flat_rows.size))
            for start in range(0, flat_rows.size, CHUNK_ROWS):  # row gathers in chunks: fastest, small temporaries
                normal[:, start : start + CHUNK_ROWS] = obs.normal_cam[flat_rows[start : start + CHUNK_ROWS]].T
            self.blocks.append(
                _Block(
                    count=count,
                    offset=sum(block.n for block in self.blocks),
                    rows=rows,
                    normal=normal,
                    log_cos_o=np.log(cos_emission[rows]),
                    brightness=obs.brightness[rows],
                    inv_var=np.asarray(inv_var, dtype=np.float64)[rows] if per_row_inv_var else None,
                )
            )
            point_ids.append(ids)
        self._finish(point_ids)

    def _finish(self, point_ids):
        self.point_ids = np.concatenate(point_ids) if point_ids else np.zeros(0, np.int64)
        self.n_points = int(sum(block.n for block in self.blocks))
        self.n_rows = int(sum(block.rows.size for block in self.blocks))
        self._ones = {block.count: np.ones(block.count) for block in self.blocks}
        self.chunks = []
        for block in self.blocks:
            step = max(1, self.chunk_rows // block.count)
            for p0 in range(0, block.n, step):
                p1 = min(block.n, p0 + step)
                self.chunks.append(_Chunk(block, slice(block.offset + p0, block.offset + p1), p0, p1))
        # Typical |b| / sigma: the reference of the noise-scale floor.
        stride = max(1, self.n_rows // 100_000)
        sample = [strided(np.abs(b.brightness) * np.sqrt(self._inv_var_of(b)), stride) for b in self.blocks]
        self.typical_brightness = float(np.median(np.concatenate(sample))) if sample else 1.0
        self.typical_brightness = self.typical_brightness or 1.0

    def subset(self, flat_points) -> "PointBlocks":
        """A layout of some of these points (increasing flat indices), cut from this one's arrays."""
        flat_points = np.asarray(flat_points, dtype=np.int64)
        sub = object.__new__(PointBlocks)
        sub.inv_var, sub.n_points_total, sub.chunk_rows = self.inv_var, self.n_points_total, self.chunk_rows
        sub.blocks, point_ids = [], []
        for block in self.blocks:
            low, high = np.searchsorted(flat_points, [block.offset, block.offset + block.n])
            local = flat_points[low:high] - block.offset
            if local.size == 0:
                continue
            sub.blocks.append(
                _Block(
                    count=block.count,
                    offset=sum(b.n for b in sub.blocks),
                    rows=block.rows[local],
                    normal=block.normal.reshape(3, block.n, block.count)[:, local].reshape(3, -1),
                    log_cos_o=block.log_cos_o[local],
                    brightness=block.brightness[local],
                    inv_var=None if block.inv_var is None else block.inv_var[local],
                    keep=None if block.keep is None else block.keep[local],
                )
            )
            point_ids.append(self.point_ids[block.offset + local])
        sub._finish(point_ids)
        return sub

    def rows(self) -> np.ndarray:
        """Row indices (into the Observations) of every row of the layout."""
        return np.concatenate([block.rows.ravel() for block in self.blocks]) if self.blocks else np.zeros(0, np.int64)

    def ones(self, count):
        return self._ones[count]

    def weight(self, chunk: _Chunk):
        """1 / sigma**2 times the keep mask, for a chunk: an array, or the scalar when uniform and all kept."""
        inv_var = chunk.rows_of("inv_var")
        keep = chunk.rows_of("keep")
        weight = self.inv_var if inv_var is None else inv_var
        return weight if keep is None else weight * keep

    def _inv_var_of(self, block: _Block):
        return self.inv_var if block.inv_var is None else block.inv_var

    @property
    def n_params(self) -> int:
        return 2 + 2 * self.n_points

    def n_rejected(self) -> int:
        return int(sum(np.count_nonzero(block.keep == 0.0) for block in self.blocks if block.keep is not None))

    def set_keep(self, keep_rows: np.ndarray) -> int:
        """Mark rows kept (True) or rejected, from an (n_obs,) mask; returns the number of rows that changed."""
        changed = 0
        for block in self.blocks:
            new = keep_rows[block.rows].astype(np.float64)
            old = np.ones_like(new) if block.keep is None else block.keep
            changed += int(np.count_nonzero(new != old))
            block.keep = None if np.all(new == 1.0) else new
        return changed

    def rows_used(self, n_obs: int, point_valid: np.ndarray) -> np.ndarray:
        """(n_obs,) bool: rows of valid points that are kept."""
        used = np.zeros(n_obs, bool)
        for block in self.blocks:
            valid = point_valid[block.offset : block.offset + block.n, None]
            kept = np.ones(block.rows.shape, bool) if block.keep is None else block.keep > 0
            used[block.rows] = kept & valid
        return used

    def per_point(self, flat_values, fill=np.nan) -> np.ndarray:
        """Scatter flat per-point values (block order) to an (n_points,) array of the Observations."""
        out = np.full(self.n_points_total, fill, dtype=np.float64)
        out[self.point_ids] = flat_values
        return out


def strided(values, stride):
    return values.ravel()[:: max(int(stride), 1)]


def light_frame(tangent) -> np.ndarray:
    """Rows: the light ``l`` (camera frame) and its derivatives ``dl/da``, ``dl/db`` in tangent coordinates."""
    a, b = float(tangent[0]), float(tangent[1])
    norm = np.sqrt(1.0 + a * a + b * b)
    light = np.array([a, b, -1.0]) / norm
    return np.stack(
        [light, (np.array([1.0, 0.0, 0.0]) - light * light[0]) / norm, (np.array([0.0, 1.0, 0.0]) - light * light[1]) / norm]
    )


# --------------------------------------------------------------------------
# Losses (IRLS weights)
# --------------------------------------------------------------------------


class Loss:
    """rho(z) and the IRLS weight psi(z)/z of a standardized residual z, threshold ``f_scale``."""

    def __init__(self, name: str, f_scale):
        if name not in LOSSES:
            raise ValueError(f"fit_varpro: loss must be one of {LOSSES}, got {name!r}")
        self.name = name
        self.f_scale = DEFAULT_F_SCALE[name] if f_scale is None else float(f_scale)
        if not (self.f_scale > 0.0):
            raise ValueError(f"fit_varpro: f_scale must be > 0, got {f_scale!r}")
        self.robust = name != "linear"

    def weight_and_rho(self, z):
        c = self.f_scale
        if self.name == "huber":
            size = np.abs(z)
            inside = size <= c
            with np.errstate(divide="ignore"):
                weight = np.where(inside, 1.0, c / size)
            return weight, np.where(inside, 0.5 * z * z, c * size - 0.5 * c * c)
        ratio = (z / c) ** 2  # cauchy
        return 1.0 / (1.0 + ratio), 0.5 * c * c * np.log1p(ratio)


HUBER = Loss("huber", None)


# --------------------------------------------------------------------------
# Streamed passes
# --------------------------------------------------------------------------


class PassSums:
    """Per-point blocks of J^T W J and J^T W r, light blocks and scalars of one pass."""

    def __init__(self, m):
        self.n_params = 2 + 2 * m
        for name in ("u11", "u12", "u22", "wa1", "wa2", "wb1", "wb2", "g1", "g2"):
            setattr(self, name, np.zeros(m))
        self.v = np.zeros(3)  # v_aa, v_ab, v_bb
        self.g_light = np.zeros(2)
        self.objective = 0.0  # the loss being minimised (0.5 sum w r^2 for linear)
        self.cost = 0.0  # 0.5 sum of squared brightness residuals over kept rows (unweighted)
        self.chi2 = 0.0  # sum of weighted squared residuals over kept rows (no robust weights)
        self.norm = 0.0  # sum of weighted squared brightness (exact-fit reference)
        self.n_rows = 0  # kept, usable rows
        self.samples = []  # |standardized residual| samples for MAD

    def mad_sigma(self) -> float:
        if not self.samples:
            return 0.0
        sample = np.concatenate(self.samples)
        return MAD_TO_SIGMA * float(np.median(sample)) if sample.size else 0.0


def chunk_geometry(chunk, frame):
    """For a chunk, shaped (P, c): cos_i floored at ``COS_INCIDENCE_FLOOR``, lit (cos_i above the floor),
    and the tangent derivatives of log cos_i (zero where unlit, as in ``koizumi.KoizumiProblem``)."""
    shape = chunk.shape
    projected = frame @ chunk.normal
    cos_i = projected[0].reshape(shape)
    lit = cos_i > COS_INCIDENCE_FLOOR
    cos_i = np.maximum(cos_i, COS_INCIDENCE_FLOOR)
    inverse = 1.0 / cos_i
    inverse *= lit
    d_log_a = projected[1].reshape(shape) * inverse
    d_log_b = projected[2].reshape(shape) * inverse
    return cos_i, lit, d_log_a, d_log_b


def point_dot(a, b):
    """Per-point sum of products along axis 1."""
    return np.einsum("pc,pc->p", a, b)


def chunk_sum(a, ones) -> float:
    """Sum of a (P, c) chunk array (per-point sums by BLAS, then their sum)."""
    return float(np.sum(a @ ones))


def dot_total(a, b):
    """Sum of the products of two arrays of the same shape (a BLAS dot product)."""
    return float(np.dot(a.ravel(), b.ravel()))




def joint_pass(layout: PointBlocks, tangent, albedo, minnaert_k, loss: Loss, scale: float, sample_stride=0):
    """Brightness residuals at (light, albedo, k): blocks of J^T W J and the gradient J^T W r.

    Residual ``r = albedo cos_i**k cos_o**(k-1) - b`` with weight ``1 /
    sigma**2`` (times the IRLS weight for a robust loss); parameters per
    point are (albedo, k), as in ``koizumi.KoizumiProblem``, and ``cos_i``
    is floored the same way. ``sample_stride > 0`` keeps every so-many
    |standardized residual| of kept rows for a MAD.
    """
    frame = light_frame(tangent)
    sums = PassSums(layout.n_points)
    v_aa = v_ab = v_bb = g_a = g_b = 0.0
    for chunk in layout.chunks:
        sl = chunk.points
        ones = layout.ones(chunk.block.count)
        rho, k = albedo[sl], minnaert_k[sl]
        brightness = chunk.rows_of("brightness")
        log_cos_o = chunk.rows_of("log_cos_o")
        kept = chunk.rows_of("keep")
        cos_i, lit, d_log_a, d_log_b = chunk_geometry(chunk, frame)
        x = np.log(cos_i)
        x += log_cos_o
        with np.errstate(over="ignore", invalid="ignore"):  # a wild trial k: infinite cost, step rejected
            shape_term = k[:, None] * x
            shape_term -= log_cos_o
            np.exp(shape_term, out=shape_term)  # cos_i^k cos_o^(k-1): exp(k x - log cos_o), not laws.minnaert_factor's bits
            residual = rho[:, None] * shape_term
            residual -= brightness
        base_weight = layout.weight(chunk)
        weighted_residual = base_weight * residual
        chi2 = dot_total(weighted_residual, residual)
        if loss.robust:
            z = residual * np.sqrt(base_weight)
            robust_weight, rho_z = loss.weight_and_rho(z / scale)
            weight = base_weight * robust_weight
            sums.objective += scale * scale * float(np.sum(rho_z))
        else:
            weight = base_weight
            sums.objective += 0.5 * chi2
        sums.chi2 += chi2
        sums.cost += 0.5 * (dot_total(residual, residual) if kept is None else dot_total(residual * kept, residual))
        sums.norm += dot_total(base_weight * brightness, brightness) if np.ndim(base_weight) else base_weight * dot_total(brightness, brightness)
        sums.n_rows += residual.size if kept is None else int(np.count_nonzero(kept))
        if sample_stride:
            z_abs = np.abs(residual) * np.sqrt(base_weight)
            sums.samples.append(strided(z_abs if kept is None else z_abs[kept > 0], sample_stride))
        q = shape_term * shape_term
        q *= weight
        h = shape_term * residual
        h *= weight
        q_x = q * x
        q_a = q * d_log_a
        q_b = q * d_log_b
        k_rho = k * rho
        sums.u11[sl] = q @ ones
        sums.u12[sl] = rho * (q_x @ ones)
        sums.u22[sl] = rho * rho * point_dot(q_x, x)
        sums.wa1[sl] = k_rho * (q_a @ ones)
        sums.wa2[sl] = k_rho * rho * point_dot(q_x, d_log_a)
        sums.wb1[sl] = k_rho * (q_b @ ones)
        sums.wb2[sl] = k_rho * rho * point_dot(q_x, d_log_b)
        k_rho2 = k_rho * k_rho
        v_aa += float(k_rho2 @ point_dot(q_a, d_log_a))
        v_ab += float(k_rho2 @ point_dot(q_a, d_log_b))
        v_bb += float(k_rho2 @ point_dot(q_b, d_log_b))
        sums.g1[sl] = h @ ones
        sums.g2[sl] = rho * point_dot(h, x)
        g_a += float(k_rho @ point_dot(h, d_log_a))
        g_b += float(k_rho @ point_dot(h, d_log_b))
    sums.v[:] = v_aa, v_ab, v_bb
    sums.g_light[:] = g_a, g_b
    return sums


def brightness_normal_equations(blocks: PointBlocks, tangent, albedo, minnaert_k) -> PassSums:
    """Blocks of ``J^T W J`` and ``J^T W r`` of the brightness residuals, ``W = 1 / sigma**2`` of ``blocks``.

    ``albedo`` and ``minnaert_k`` are flat per-point arrays in the blocks'
    order (``blocks.point_ids``). The returned sums hold ``v`` (v_aa, v_ab,
    v_bb), per point ``u11, u12, u22`` (albedo, k), ``wa1, wa2, wb1, wb2``
    (light rows a, b; point columns albedo, k), the gradients, and ``chi2``.
    Used by ``fisher`` for the information matrix.
    """
    return joint_pass(blocks, tangent, albedo, minnaert_k, Loss("linear", None), 1.0)
