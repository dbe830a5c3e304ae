"""The starting light of the joint fits: a coarse-to-fine grid over the light's tangent coordinates.

Both ``koizumi.fit_koizumi_lm`` and ``varpro.fit_varpro`` start from the
best node of a grid over the light's tangent coordinates
(``core.light_from_tangent``), scored by a *profile cost*: the brightness
cost of a light with every point's albedo and k from the closed-form
log-space fit under it. Each estimator brings its own score (a callable on
an (N, 2) array of tangents): ``koizumi.profile_cost`` one light at a time on
its ``KoizumiProblem``, ``varpro`` all lights of a batch at once on its
``PointBlocks`` (unlit rows predicted dark, ``1 / sigma**2`` weights). The
grid and its refinement are the one :func:`grid_search` here; they differ
only in ``keep_best``.

Why a grid: when the albedo varies from point to point, a single-albedo
(Iwano, Lambert) guess can be many degrees off along the spin axis, where
the joint cost has a long, shallow valley; with few views per point and
noise a local solver then stops in a local minimum. The profile cost is
cheap and its minimum over a grid lands in the right basin.
"""

from __future__ import annotations

import numpy as np

__all__ = ["evenly_spaced", "grid_search"]


def evenly_spaced(ids, n):
    """At most ``n`` of ``ids``, evenly spaced in their order (all of them when there are no more than ``n``)."""
    if ids.size <= n:
        return ids
    return ids[np.linspace(0, ids.size - 1, n).astype(np.int64)]


def _square_grid(offsets) -> np.ndarray:
    """(len(offsets)**2, 2) nodes, the first coordinate outer."""
    return np.stack(np.meshgrid(offsets, offsets, indexing="ij"), -1).reshape(-1, 2)


def grid_search(score, guess_tangent, *, half_width=0.8, n_grid=17, n_refine=2, keep_best=False) -> np.ndarray:
    """Coarse-to-fine grid search of the tangent coordinates minimising ``score``; returns the best (2,) tangent.

    The grid covers ``[-half_width, half_width]**2`` (light angles up to
    about 39 deg along the axes at 0.8) with ``n_grid**2`` nodes; each of
    ``n_refine`` levels then searches a 7x7 grid over +-1 cell around the
    best node with a 3x finer step. ``score`` maps an (N, 2) array of
    tangents to their (N,) costs; a non-finite cost never wins.

    ``keep_best`` says how a level's winner is chosen:

    - False: the lowest cost among the level's own nodes (the first of
      equal ones); ``guess_tangent`` (or None) is one more node of the first
      level. (``varpro``)
    - True: the best node so far, starting from ``guess_tangent``, is kept
      unless a node of the level has a strictly lower cost; a guess whose
      cost is NaN is therefore never replaced. (``koizumi``)
    """
    if keep_best:
        best = np.asarray(guess_tangent, dtype=np.float64)
        best_cost = score(best[None])[0]
    candidates = _square_grid(np.linspace(-half_width, half_width, n_grid))
    if not keep_best and guess_tangent is not None:
        candidates = np.vstack([guess_tangent, candidates])
    step = 2.0 * half_width / (n_grid - 1)
    for level in range(n_refine + 1):
        if level:
            candidates = best + _square_grid(np.linspace(-step, step, 7))
            step /= 3.0
        costs = score(candidates)
        costs = np.where(np.isfinite(costs), costs, np.inf)
        index = int(np.argmin(costs))
        if not keep_best:
            best = candidates[index]
        elif costs[index] < best_cost:
            best, best_cost = candidates[index], costs[index]
    return best
