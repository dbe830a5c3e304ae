#!/usr/bin/env python3
"""Benchmark the refinement's per-point fit of a normal, an albedo and a k (``refine.refine_points``).

The refinement fits, at each of its 11 offsets, every candidate point of a
cloud (60,000 by default) to its pure samples: the point's normal (turned
about the spin axis, or tilted freely), its albedo and its Minnaert k, with
the light held and the starting normal as a prior. This script makes one
synthetic set of such samples (points with random normals facing a ring of
36 cameras about the y axis, 6 to 20 samples each from the views that see
them lit, 1 % noise, the fit started from normals turned by about 5 deg and
albedo and k 10 % off) and fits it, in this one process, with

(a) ``naive``: what a newcomer would write, a Python loop over the points,
    each fitted with ``scipy.optimize.least_squares`` to the same cost (the
    brightness residuals and the normal's prior). It runs on
    ``--naive-points`` points (evenly spaced) and its time is extrapolated
    linearly to the whole set; the output says so.
(b) ``refine_points``: the vectorised Levenberg-Marquardt of the workflow,
    every point at once.

It prints the seconds of each (best of ``--repeats``), their ratio, and how
far the two answers lie apart on the naive points: the median angle between
their normals, the share of points whose normals agree within 0.01 deg, and
the median albedo and k differences. Where they disagree, one of the two
stopped in another minimum or at refine_points' bounds (a normal turned at
most 45 deg, k in [0.05, 2]), which the naive fit does not have. Both modes are timed: about the spin axis (the paper's sets)
and free (views out of the ring's plane).

    .venv/bin/python bench/bench_refine.py                # 60,000 points, ~1 min
    .venv/bin/python bench/bench_refine.py --points 20000 --naive-points 200

BLAS runs single-threaded, as in the workflow's jobs on a busy machine.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from asteroid_photometry.from_images import refine  # noqa: E402
from asteroid_photometry.reflectance.laws import minnaert_brightness  # noqa: E402
from timing import best_of  # noqa: E402

SPIN_AXIS = np.array([0.0, 1.0, 0.0])
LIGHT_DEG = 10.0
NORMAL_PRIOR_DEG = 10.0
N_ITERATIONS = 30  # as the refinement runs it (refine._fit_candidates)


def rotation_about_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def synthetic_samples(n_points: int, n_views: int, noise: float, seed: int):
    """Samples of ``n_points`` Minnaert points seen from a ring of ``n_views`` cameras; the truth and a perturbed start."""
    rng = np.random.default_rng(seed)
    light_cam = np.array([np.sin(np.radians(LIGHT_DEG)), 0.0, -np.cos(np.radians(LIGHT_DEG))])
    view_cam = np.array([0.0, 0.0, -1.0])
    rotations = np.stack([rotation_about_y(2 * np.pi * i / n_views) for i in range(n_views)])  # body to camera
    normals = rng.normal(size=(3 * n_points, 3)) * [1.0, 0.5, 1.0]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cos_i = normals @ np.einsum("nji,j->ni", rotations, light_cam).T  # (points, views)
    cos_o = normals @ np.einsum("nji,j->ni", rotations, view_cam).T
    seen = (cos_i > 0.1) & (cos_o > 0.2)
    enough = np.flatnonzero(seen.sum(axis=1) >= 6)[:n_points]  # points lit and seen in 6 views or more
    normals, cos_i, cos_o, seen = normals[enough], cos_i[enough], cos_o[enough], seen[enough]
    albedo, k = rng.uniform(0.3, 0.8, n_points), rng.uniform(0.6, 1.0, n_points)
    point_index, image_index = [], []
    for point in range(n_points):
        views = np.flatnonzero(seen[point])
        chosen = rng.choice(views, size=min(len(views), int(rng.integers(6, 21))), replace=False)
        point_index.append(np.full(len(chosen), point)), image_index.append(np.sort(chosen))
    point_index, image_index = np.concatenate(point_index), np.concatenate(image_index)
    truth_b = minnaert_brightness(albedo[point_index], k[point_index], cos_i[point_index, image_index], cos_o[point_index, image_index])
    brightness = truth_b * (1.0 + noise * rng.normal(size=len(truth_b)))
    start = refine._turn(normals, SPIN_AXIS, np.radians(rng.normal(0.0, 5.0, n_points)))
    north = SPIN_AXIS - (start @ SPIN_AXIS)[:, None] * start  # along the meridian: the latitude's direction
    tilt = start + np.tan(np.radians(rng.normal(0.0, 3.0, n_points)))[:, None] * north / np.linalg.norm(north, axis=1, keepdims=True)
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    samples = dict(
        point_index=point_index, rotations=rotations[image_index], view_cam=np.tile(view_cam, (len(point_index), 1)), brightness=brightness,
        albedo=albedo * rng.uniform(0.9, 1.1, n_points), minnaert_k=k * rng.uniform(0.9, 1.1, n_points), light_dir_cam=light_cam,
        noise_var=float(np.median(truth_b) * noise) ** 2,
    )
    return samples, {"spin axis": start, "free": tilt}


def naive_fit(samples, start_normals, points, axis):
    """Each of ``points`` fitted on its own with scipy's least_squares, to refine_points' cost."""
    prior = np.sqrt(samples["noise_var"]) / np.radians(NORMAL_PRIOR_DEG)
    light_b_all = np.einsum("nji,j->ni", samples["rotations"], samples["light_dir_cam"])
    view_b_all = np.einsum("nji,nj->ni", samples["rotations"], samples["view_cam"])
    order = np.argsort(samples["point_index"], kind="stable")
    bounds = np.searchsorted(samples["point_index"][order], [points, points + 1])
    out = np.empty((len(points), 5))
    for row, point in enumerate(points):
        rows = order[bounds[0][row]:bounds[1][row]]
        light_b, view_b, observed = light_b_all[rows], view_b_all[rows], samples["brightness"][rows]
        n0 = start_normals[point]
        e1, e2 = (np.cross(axis, n0), None) if axis is not None else refine._tangent_basis(n0[None])

        def normal_of(x):
            if axis is not None:
                return refine._turn(n0[None], axis, np.array([x[0]]))[0]
            n = n0 + x[0] * e1[0] + x[1] * e2[0]
            return n / np.linalg.norm(n)

        def residuals(x):
            n = normal_of(x)
            albedo, k = x[-2], x[-1]
            model = minnaert_brightness(albedo, k, np.maximum(light_b @ n, refine.COS_FLOOR), np.maximum(view_b @ n, refine.COS_FLOOR))
            return np.concatenate([model - observed, prior * (n - n0)])

        turns = [0.0] if axis is not None else [0.0, 0.0]
        fit = least_squares(residuals, [*turns, samples["albedo"][point], samples["minnaert_k"][point]], method="lm")
        out[row] = [*normal_of(fit.x), fit.x[-2], fit.x[-1]]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=60000)
    parser.add_argument("--views", type=int, default=36)
    parser.add_argument("--naive-points", type=int, default=300)
    parser.add_argument("--noise", type=float, default=0.01)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    samples, starts = synthetic_samples(args.points, args.views, args.noise, args.seed)
    naive_points = np.linspace(0, args.points - 1, min(args.naive_points, args.points)).astype(int)
    print(f"{args.points} points, {len(samples['brightness'])} samples ({args.views} views, noise {args.noise:g}); naive on {len(naive_points)} points, extrapolated")
    print(f"{'mode':<12}{'naive s':>12}{'refine_points s':>18}{'ratio':>9}{'normals apart deg':>19}{'agree':>8}{'albedo apart':>15}{'k apart':>10}")
    for mode, start in starts.items():
        axis = SPIN_AXIS if mode == "spin axis" else None
        fast_s, (normals, albedo, k, _) = best_of(args.repeats, lambda: refine.refine_points(
            samples["point_index"], samples["rotations"], samples["view_cam"], samples["brightness"], start, samples["albedo"],
            samples["minnaert_k"], samples["light_dir_cam"], n_iterations=N_ITERATIONS, min_observations=6, normal_prior_deg=NORMAL_PRIOR_DEG,
            noise_var=samples["noise_var"], axis=axis,
        ))
        naive_s, naive = best_of(args.repeats, lambda: naive_fit(samples, start, naive_points, axis))
        naive_s *= args.points / len(naive_points)
        apart = np.degrees(np.arccos(np.clip(np.sum(normals[naive_points] * naive[:, :3], axis=1), -1.0, 1.0)))
        print(
            f"{mode:<12}{naive_s:>12.1f}{fast_s:>18.2f}{naive_s / fast_s:>9.0f}{np.median(apart):>19.2g}{np.mean(apart < 0.01):>8.0%}"
            f"{np.median(np.abs(albedo[naive_points] - naive[:, 3])):>15.2g}{np.median(np.abs(k[naive_points] - naive[:, 4])):>10.2g}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
