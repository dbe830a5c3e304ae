#!/usr/bin/env python3
"""Benchmark one step of the mesh fit (``mesh_light.fit_mesh_light``): the normal matrix's assembly and the damped solve.

Rule ``mesh_light`` is the workflow's largest stage (about half of its
job-seconds), and most of each of its fits goes into eight solves of a system
the size of the surface's vertices. This script builds that system at the
size of a paper set's fit (by default a geodesic sphere of 163,842 vertices,
2,936 cells, 36 images on the equator, about 2 million samples of 1 %
noise; the matrix is the Jacobian's column-scaled normal matrix, assembled as
the fit assembles it). In this one process it assembles the normal matrix J'J + P'P with

- ``J.T @ J``: scipy's sparse product, the priors' matrix added, as the fit
  assembled it before (its pattern found again at every step);
- ``assembly``: ``mesh_light._NormalMatrix``, sums of products by face, by
  column and image, and by image, put into a pattern made once per cast (timed
  apart);

and prints their seconds (best of ``--repeats``), ratio and how far the two
matrices differ. Then it solves one damped step with

(a) ``whole LU``: one sparse LU of the whole system in COLAMD's order, as the
    fit solved it before c033565;
(b) ``dissection``: one double precision LU in the problem's elimination
    order (a nested dissection of the surface, the unknowns every sample or
    every image's samples share last; made once per fit, timed apart), as the
    fit solved it until the single precision LU;
(c) ``single + CG``: ``mesh_light._solve``, a single precision LU in that
    order, the step refined in double precision by conjugate gradients with
    that LU as the preconditioner.

It prints the seconds of each (best of ``--repeats``), the ratios of (a) and
(b) to (c), the fill of each factorisation and how far the steps lie apart
from (a)'s (largest difference over the step's largest entry; they solve the
same system, so round-off).

    .venv/bin/python bench/bench_mesh_step.py                   # 163,842 vertices, ~1 min
    .venv/bin/python bench/bench_mesh_step.py --subdivisions 6  # 40,962 vertices

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
import scipy.sparse as sp  # noqa: E402
from scipy.sparse.linalg import splu  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from asteroid_photometry.from_images import mesh_light  # noqa: E402
from timing import best_of  # noqa: E402

N_IMAGES = 36
LIGHT_DEG = 10.0
SAMPLES_PER_FACE = 6.0  # over all images, as on a paper set (1.45 million samples on 232,000 faces)
DAMPING = 1e-5
EDGE_FOOTPRINTS = 1.7  # the surface's median edge in pixel footprints, about as on a paper set


def rotation_about_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def step_system(subdivisions: int, seed: int):
    """The column-scaled normal matrix, its gradient, the problem and the samples' count of one step of the fit on a
    geodesic sphere."""
    import open3d as o3d

    rng = np.random.default_rng(seed)
    # A geodesic sphere: every vertex with five or six neighbours, as on the fit's subdivided Poisson surface (a UV
    # sphere's poles, each a vertex of hundreds of faces, would time the ordering of two dense rows instead).
    mesh = o3d.geometry.TriangleMesh.create_icosahedron(radius=1.0).subdivide_midpoint(number_of_iterations=subdivisions)
    vertices = np.asarray(mesh.vertices) / np.linalg.norm(np.asarray(mesh.vertices), axis=1, keepdims=True)
    triangles = np.asarray(mesh.triangles).copy()
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    mesh.compute_vertex_normals()
    edge = np.median(np.linalg.norm(vertices[triangles[:, 0]] - vertices[triangles[:, 1]], axis=1))
    settings = mesh_light.MeshLightSettings()
    problem = mesh_light._MeshProblem(vertices, triangles, np.asarray(mesh.vertex_normals).copy(), edge / EDGE_FOOTPRINTS, N_IMAGES, 0.02, settings)
    rotations = np.array([rotation_about_y(2 * np.pi * i / N_IMAGES) for i in range(N_IMAGES)])
    light = np.array([np.sin(np.radians(LIGHT_DEG)), 0.0, -np.cos(np.radians(LIGHT_DEG))])
    normals = problem.surface(np.zeros(problem.nv))[4]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    faces, images, views = [], [], []
    for i, R in enumerate(rotations):
        view = R.T @ np.array([0.0, 0.0, -1.0])  # towards the camera, body frame
        seen = np.flatnonzero((normals @ view > settings.min_cos_emission) & (normals @ (R.T @ light) > settings.min_cos_incidence))
        seen = seen[rng.uniform(size=len(seen)) < SAMPLES_PER_FACE / N_IMAGES * 2.5]  # about 40 % of the faces seen
        faces.append(seen)
        images.append(np.full(len(seen), i))
        views.append(np.broadcast_to(view, (len(seen), 3)))
    face, image, view = np.concatenate(faces), np.concatenate(images), np.concatenate(views)
    samples = mesh_light._Samples(face, image, view, rng.normal(-1.0, 0.01, len(face)), np.full(len(face), 0.01))
    cell = problem.cell[face]
    samples.columns = np.column_stack([
        triangles[face], problem.o_a + cell, np.full(len(face), problem.o_k), problem.o_dk + cell,
        np.full(len(face), problem.o_l), np.full(len(face), problem.o_l + 1), problem.o_g + image,
    ])
    state = mesh_light._State(np.zeros(problem.nv), np.full(problem.ncell, -1.2), 0.8, np.zeros(problem.ncell), light, np.zeros(N_IMAGES))
    r, prior_r, J = mesh_light._residuals(problem, samples, state, rotations, jacobian=True)
    normal, colnorm = mesh_light._NormalMatrix(problem, samples).scaled(J.data)
    gradient = -(J.T @ r + problem.prior.T @ prior_r) / colnorm
    return normal, gradient, problem, samples, J


def product_normal(J, prior_normal):
    """The normal matrix as the fit assembled it before: scipy's product of J' and J (its pattern found again at every
    step), the priors' added, every diagonal entry stored, in CSC."""
    return (J.T @ J + prior_normal + sp.identity(J.shape[1], format="csr") * 0.0).tocsc()


def whole_lu(normal, gradient, damping):
    """The step as the fit solved it before: one LU of the whole damped system, in COLAMD's order."""
    damped = normal.copy()
    damped.setdiag(damped.diagonal() + damping)
    lu = splu(damped, permc_spec="COLAMD", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    return lu.solve(gradient), lu.L.nnz + lu.U.nnz


def dissection_lu(normal, gradient, damping, order):
    """The step as the fit solved it until the single precision LU: one double precision LU in the problem's order."""
    damped = normal.copy()
    damped.setdiag(damped.diagonal() + damping)
    lu = mesh_light._lu(damped[order][:, order].tocsc())
    y = np.empty_like(gradient)
    y[order] = lu.solve(gradient[order])
    return y, lu.L.nnz + lu.U.nnz


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, default=7, help="the geodesic sphere's subdivisions of an icosahedron; 7: 163,842 vertices, 6: 40,962")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    normal, gradient, problem, samples, J = step_system(args.subdivisions, args.seed)
    print(f"system: {problem.n_par} unknowns ({problem.nv} heights, {problem.ncell} cells, {3 + problem.n_images} shared), "
          f"{len(samples.face)} samples, {normal.nnz} stored entries")
    # The normal matrix, unscaled: scipy's product against the fit's assembly (its pattern made once per cast, timed apart).
    t_product, by_product = best_of(args.repeats, lambda: product_normal(J, problem.prior_normal))
    t_pattern, assembly = best_of(args.repeats, lambda: mesh_light._NormalMatrix(problem, samples))
    t_assembly, assembled = best_of(args.repeats, lambda: assembly(J.data))
    differ = abs(by_product - assembled).max() / abs(by_product).max()
    print(f"{'normal matrix':14s} {'seconds':>8s}")
    print(f"{'J.T @ J':14s} {t_product:8.2f}")
    print(f"{'assembly':14s} {t_assembly:8.2f}   (its pattern, once per cast: {t_pattern:.2f} s)")
    print(f"ratio J.T @ J / assembly: {t_product / t_assembly:.2f}; the two matrices differ by {differ:.1e} of the largest entry")
    t_whole, (y_whole, fill) = best_of(args.repeats, lambda: whole_lu(normal, gradient, DAMPING))
    t_double, (y_double, dissected_fill) = best_of(args.repeats, lambda: dissection_lu(normal, gradient, DAMPING, problem.order))
    t_new, y_new = best_of(args.repeats, lambda: mesh_light._solve(normal, gradient, DAMPING, problem.order))
    t_order, _ = best_of(args.repeats, lambda: problem._elimination_order(problem.F))
    apart = max(np.abs(y - y_whole).max() for y in (y_double, y_new)) / np.abs(y_whole).max()
    print(f"{'solver':12s} {'seconds':>8s} {'fill':>11s}")
    print(f"{'whole LU':12s} {t_whole:8.2f} {fill:11d}")
    print(f"{'dissection':12s} {t_double:8.2f} {dissected_fill:11d}   (its order, once per fit: {t_order:.2f} s)")
    print(f"{'single + CG':12s} {t_new:8.2f} {dissected_fill:11d}   (the same fill, in single precision)")
    print(f"ratio whole LU / single + CG: {t_whole / t_new:.2f}, dissection / single + CG: {t_double / t_new:.2f}; "
          f"steps apart by at most {apart:.1e} of the step's largest entry")
    return t_whole / t_new, apart, t_product / t_assembly, differ


if __name__ == "__main__":
    main()
