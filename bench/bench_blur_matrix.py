#!/usr/bin/env python3
"""Benchmark the mesh fit's PSF blur matrix (``mesh_light._blur_matrix``) against the assembly it replaced.

Under a point spread function, every cast of the mesh fit (two a fit) builds a
sparse matrix from the surface's lit pixels (the support) to the samples: a
sample's value is the PSF-weighted sum of the support pixels around it. This
script builds that matrix at the size of a paper set's fit (36 images of
512 x 512 pixels, a lit disc of about 1.6 million support pixels, the samples
those a pixel inside its edge, thinned as the cuts thin them; the PSF core of
the ``amica`` condition, 5 x 5), in this one process, with

(a) ``coo``: the assembly the fit used before: one (row, column, weight)
    triple per kernel entry and sample that meets the support, sorted into
    CSR by scipy;
(b) ``gather``: ``mesh_light._blur_matrix``: every row holds the whole kernel
    (a neighbour outside the support as a zero weight), gathered one kernel
    entry at a time from a lookup of the support on padded images, no sort.

It prints the seconds of each (best of ``--repeats``), their ratio, and
whether the two matrices give the same products, to the last bit, on random
support values (they must: the fit's results may not move).

    .venv/bin/python bench/bench_blur_matrix.py               # ~30 s
    .venv/bin/python bench/bench_blur_matrix.py --radius 80   # smaller discs
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from asteroid_photometry.from_images import mesh_light  # noqa: E402
from asteroid_photometry.world.degrade import psf_kernel  # noqa: E402
from timing import best_of  # noqa: E402

N_IMAGES = 36
SIZE = 512
FWHM_PX = 1.5


def coo_blur_matrix(psf: np.ndarray, sample_pixel, support_pixel, shape) -> sp.csr_matrix:
    """The blur matrix as the fit assembled it before: COO triples of the kernel entries that meet the support."""
    n_images, height, width = shape
    lookup = np.full(n_images * height * width, -1, dtype=np.int64)
    lookup[support_pixel] = np.arange(len(support_pixel))
    image, rest = np.divmod(sample_pixel, height * width)
    v, u = np.divmod(rest, width)
    radius = psf.shape[0] // 2
    rows, cols, vals = [], [], []
    for dv in range(-radius, radius + 1):
        for du in range(-radius, radius + 1):
            vv, uu = v + dv, u + du
            inside = (vv >= 0) & (vv < height) & (uu >= 0) & (uu < width)
            target = np.where(inside, lookup[image * height * width + np.clip(vv, 0, height - 1) * width + np.clip(uu, 0, width - 1)], -1)
            hit = np.flatnonzero(target >= 0)
            rows.append(hit)
            cols.append(target[hit])
            vals.append(np.full(len(hit), psf[dv + radius, du + radius]))
    rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    return sp.csr_matrix((vals, (rows, cols)), shape=(len(sample_pixel), len(support_pixel)))


def pixels(radius: float, seed: int):
    """Support and sample pixels (flat indices into the stack of images): a lit disc per image, off centre by a few
    pixels from image to image; the samples those a pixel inside its edge, 90 % of them (the cosine cuts)."""
    rng = np.random.default_rng(seed)
    vv, uu = np.mgrid[0:SIZE, 0:SIZE]
    support, samples = [], []
    for i in range(N_IMAGES):
        cv, cu = SIZE / 2 + rng.uniform(-8, 8, 2)
        distance = np.hypot(vv + 0.5 - cv, uu + 0.5 - cu).ravel()
        lit = np.flatnonzero(distance < radius)
        inner = np.flatnonzero((distance < radius - 1.5) & (rng.uniform(size=distance.size) < 0.9))
        support.append(i * SIZE * SIZE + lit)
        samples.append(i * SIZE * SIZE + inner)
    return np.concatenate(samples), np.concatenate(support)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--radius", type=float, default=120.0, help="the lit disc's radius in pixels (120: about 1.6 million support pixels)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    psf = psf_kernel(FWHM_PX, radius_px=2)
    samples, support = pixels(args.radius, args.seed)
    shape = (N_IMAGES, SIZE, SIZE)
    print(f"{len(samples)} samples, {len(support)} support pixels, kernel {psf.shape[0]} x {psf.shape[1]}")
    t_coo, coo = best_of(args.repeats, lambda: coo_blur_matrix(psf, samples, support, shape))
    t_gather, gather = best_of(args.repeats, lambda: mesh_light._blur_matrix(psf, samples, support, shape))
    values = np.random.default_rng(args.seed + 1).uniform(0.1, 1.0, len(support))
    same = bool(np.array_equal(coo @ values, gather @ values))
    print(f"{'assembly':8s} {'seconds':>8s} {'stored':>10s}")
    print(f"{'coo':8s} {t_coo:8.2f} {coo.nnz:10d}")
    print(f"{'gather':8s} {t_gather:8.2f} {gather.nnz:10d}")
    print(f"ratio coo / gather: {t_coo / t_gather:.1f}; products the same to the last bit: {same}")
    return t_coo / t_gather, same


if __name__ == "__main__":
    main()
