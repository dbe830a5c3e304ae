"""The light from a shape from shading on one mesh: heights, albedo, k, gains and the light fitted to every pixel.

The refinement (``refine``) fits the light to a few thousand pure samples,
each the mean of four pixels around a cloud point whose normal was fitted to
it. Under a point spread function those samples mix their neighbours'
shading, and the normals were fitted under the light the refinement started
from; both leave an elevation error of one to four degrees in the light on
``amica``-like images (docs/amica_record.md, "A shape from shading on one
mesh"). This stage fits the light to the whole image instead.

The surface is the cloud's Poisson surface subdivided to about
``edge_px`` pixel footprints. Every pixel of every registered image whose ray
meets it, ``margin`` pixels inside the silhouette and every cast shadow, lit
and seen above the cosine cuts, is a sample of log brightness. The unknowns,
fitted together by Levenberg-Marquardt on the sparse Jacobian:

- each vertex's height along its normal, held to the Poisson surface
  (``sigma_h_px``) and to its neighbours (``sigma_edge_px``);
- a log albedo and a k offset per cube of ``cell_px`` (the offsets held to
  the body's k by ``sigma_dk``), and the body's k;
- the light (two angles about the current direction);
- a log gain per image on top of the refinement's gains, held by half the
  mission's stated calibration scatter, their mean at zero (the albedo scale
  stays the images').

Lengths are in pixel footprints, so a reconstruction without navigation
priors (in its own scale) gets the same settings. Residuals in log brightness
are over the sensor's noise plus a relative floor (``floor``), weighed by a
Cauchy loss of ``robust`` sigmas. The samples are cast again after every
``inner`` steps, ``outer`` times. Each step solves the damped, column-scaled
normal equations by conjugate gradients preconditioned with a single
precision sparse LU, its unknowns eliminated in a nested dissection of the
surface (``_dissection_order``).

Everything comes from the images, the reconstruction and the refinement's
output: no truth is read.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.ndimage import binary_erosion
from scipy.spatial import ConvexHull, QhullError
from scipy.sparse.linalg import LinearOperator, cg, splu

from asteroid_photometry.world.cameras import Intrinsics, pixel_rays_cam, project

log = logging.getLogger(__name__)

#: Cosines below which a sample's model is clamped and its residual dropped during the fit.
COS_CLAMP = 0.02
#: Rays to the Sun leave the surface this many pixel footprints along the normal (no self-hit).
SHADOW_OFFSET_PX = 0.035
#: Damping floor of Levenberg-Marquardt (of the column-scaled system) and attempts per step.
MIN_DAMPING = 1e-6
MAX_ATTEMPTS = 6
#: A sample's Jacobian columns fixed by its face (``_Samples.columns``: heights, albedo, k, k offset, light); the last is its image's gain.
FACE_SLOTS = 8
#: The log gains' prior sigma where the mission states no calibration scatter (the gains held at one).
GAINS_HELD = 1e-6


@dataclass(frozen=True)
class MeshLightSettings:
    """The fit's settings (docs/table2.md, section 13; chosen on config/tuning.yaml's and config/tuning_mid.yaml's sets)."""

    edge_px: float = 2.5
    sigma_h_px: float = 1.4
    sigma_edge_px: float = 0.35
    # Cells of 7 footprints, the k offsets held by 0.1, with the mission's PSF in the model (``psf``): the three
    # together, not one alone, remove the map's lean on the true geometry; chosen on config/tuning_mid.yaml's and
    # config/map_draws.yaml's rows (docs/table2.md, section 16).
    cell_px: float = 7.0
    sigma_dk: float = 0.1
    floor: float = 0.02
    min_cos_emission: float = 0.2
    min_cos_incidence: float = 0.1
    outer: int = 2
    inner: int = 4
    robust: float = 3.0
    margin: int = 1
    damping: float = 1e-5
    damping_down: float = 10.0


@dataclass(frozen=True)
class MeshLight:
    """The fit's result: the light (camera frame), the body's k, the log gains on top of the start's, its size and its surface."""

    light_dir_cam: np.ndarray
    minnaert_k: float
    log_gains: np.ndarray  # by registered image, in the order of ``image_indices``
    image_indices: np.ndarray
    n_samples: int
    n_vertices: int
    n_steps: int
    cost: np.ndarray  # after every accepted step
    vertices: np.ndarray  # the fitted surface: its vertices at the fitted heights (the cloud's frame)
    triangles: np.ndarray


def _light_basis(light):
    first = np.cross(light, [0.0, 1.0, 0.0])
    if np.linalg.norm(first) < 1e-3:
        first = np.cross(light, [1.0, 0.0, 0.0])
    first /= np.linalg.norm(first)
    return first, np.cross(light, first)


class _MeshProblem:
    """The unknowns' layout, the mesh and its fixed prior rows."""

    def __init__(self, vertices, triangles, normals, footprint: float, n_images: int, gain_sigma: float, settings: MeshLightSettings):
        self.P0, self.F, self.D = vertices, triangles, normals
        self.settings = settings
        self.footprint = footprint
        self.nv = len(vertices)
        centroids = vertices[triangles].mean(axis=1)
        _, cell = np.unique(np.floor(centroids / (settings.cell_px * footprint)).astype(np.int64), axis=0, return_inverse=True)
        self.cell = cell.ravel()
        self.ncell = int(self.cell.max()) + 1
        self.n_images = n_images
        # Unknowns: heights (nv), log albedo (ncell), body k (1), k offsets (ncell), light (2), log gains (n_images).
        self.o_a = self.nv
        self.o_k = self.o_a + self.ncell
        self.o_dk = self.o_k + 1
        self.o_l = self.o_dk + self.ncell
        self.o_g = self.o_l + 2
        self.n_par = self.o_g + n_images
        self.edges = edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1), axis=0)
        sigma_h, sigma_edge = settings.sigma_h_px * footprint, settings.sigma_edge_px * footprint
        self.gain_sigma = max(gain_sigma / 2, GAINS_HELD)  # half the stated scatter; none stated: held at one
        ne, nc, ni = len(edges), self.ncell, n_images
        rows = np.concatenate([np.arange(self.nv), np.tile(self.nv + np.arange(ne), 2), self.nv + ne + np.arange(nc), self.nv + ne + nc + np.arange(ni), np.full(ni, self.nv + ne + nc + ni)])
        cols = np.concatenate([np.arange(self.nv), edges[:, 0], edges[:, 1], self.o_dk + np.arange(nc), self.o_g + np.arange(ni), self.o_g + np.arange(ni)])
        vals = np.concatenate([np.full(self.nv, 1 / sigma_h), np.full(ne, 1 / sigma_edge), np.full(ne, -1 / sigma_edge), np.full(nc, 1 / settings.sigma_dk), np.full(ni, 1 / self.gain_sigma), np.full(ni, 1e3)])
        # The priors are linear in the unknowns: one fixed matrix, its residual that matrix times the unknowns.
        self.prior = sp.csr_matrix((vals, (rows, cols)), shape=(self.nv + ne + nc + ni + 1, self.n_par))
        self.prior_normal = (self.prior.T @ self.prior).tocsr()
        self.order = self._elimination_order(triangles)

    def _elimination_order(self, triangles) -> np.ndarray:
        """The order the step's LU eliminates the unknowns in: the heights and each cell's albedo and k offset in a
        nested dissection of the surface, then the unknowns every sample or every image's samples share (the body's k,
        the light, the gains), whose rows of the normal matrix are dense."""
        cell_vertices = sp.csr_matrix((np.ones(3 * len(triangles)), (np.repeat(self.cell, 3), triangles.ravel())), shape=(self.ncell, self.nv))
        cell_vertices.sum_duplicates()
        order = _dissection_order(self.P0, self.edges, cell_vertices)
        # A cell's albedo and k offset are eliminated one after the other, where the dissection puts the cell.
        order = np.repeat(order, np.where(order >= self.nv, 2, 1))
        slot = order >= self.nv
        cell = order[slot] - self.nv
        order[slot] = np.where(np.arange(len(cell)) % 2 == 0, self.o_a + cell, self.o_dk + cell)
        return np.concatenate([order, [self.o_k, self.o_l, self.o_l + 1], self.o_g + np.arange(self.n_images)])

    def surface(self, h):
        """Vertices, triangle corners, unnormalised face normals and their lengths at heights ``h``."""
        P = self.P0 + h[:, None] * self.D
        a, b, c = P[self.F[:, 0]], P[self.F[:, 1]], P[self.F[:, 2]]
        cross = np.cross(b - a, c - a)
        return P, a, b, c, cross, np.linalg.norm(cross, axis=1)


@dataclass
class _Pixels:
    """Pixels that see the surface: the face each sees, its image (position among the registered images) and the
    direction towards the camera (unit, body frame)."""

    face: np.ndarray
    image: np.ndarray
    view: np.ndarray


@dataclass
class _Samples:
    face: np.ndarray
    image: np.ndarray  # position among the registered images
    view: np.ndarray  # unit, towards the camera, body frame
    log_brightness: np.ndarray
    sigma: np.ndarray
    columns: np.ndarray | None = None  # (m, 9) the Jacobian's columns of each sample
    # Under a point spread function: every lit pixel that sees the surface (``support``), and the blur as a matrix,
    # a sample's value the PSF-weighted sum of its support pixels' brightness (``blur``, samples x support).
    support: _Pixels | None = None
    blur: sp.csr_matrix | None = None


def _compact(labels, n_labels: int):
    """Each of ``labels`` (integers in [0, ``n_labels``)) numbered among those present, in increasing order, and the
    position of each present label's first occurrence."""
    present = np.zeros(n_labels, bool)
    present[labels] = True
    number = np.cumsum(present) - 1
    first = np.empty(n_labels, np.int64)
    first[labels[::-1]] = np.arange(len(labels) - 1, -1, -1)  # the last write wins: the first occurrence
    return number[labels], first[present]


def _blur_matrix(psf: np.ndarray, sample_pixel, support_pixel, shape) -> sp.csr_matrix:
    """The PSF as a (samples x support) matrix: row i holds the weight of each support pixel in sample i's value.

    Pixels are flat indices into the stack of images of ``shape`` (images, height, width); a neighbour outside its
    image or not in the support (sky, shadow, the unlit side) adds nothing: its entry is stored as a zero weight on
    the first support pixel, so that every row holds the whole kernel, in its row-major order (the support being in
    pixel order, that of the pixels), and the matrix is built without a search."""
    n_images, height, width = shape
    radius = psf.shape[0] // 2
    # The support's positions on images padded by the kernel's radius (-1: not in the support), so that no neighbour
    # of a sample falls outside its image's array.
    padded_height, padded_width = height + 2 * radius, width + 2 * radius
    lookup = np.full(n_images * padded_height * padded_width, -1, dtype=np.int32)
    image, rest = np.divmod(support_pixel, height * width)
    v, u = np.divmod(rest, width)
    lookup[(image * padded_height + v + radius) * padded_width + u + radius] = np.arange(len(support_pixel))
    image, rest = np.divmod(sample_pixel, height * width)
    v, u = np.divmod(rest, width)
    centre = (image * padded_height + v + radius) * padded_width + u + radius
    dv, du = np.divmod(np.arange(psf.size), psf.shape[1])
    # Gathered one kernel entry at a time into contiguous rows, then laid out sample by sample.
    by_entry = np.empty((psf.size, len(sample_pixel)), dtype=np.int32)
    for j, shift in enumerate((dv - radius) * padded_width + (du - radius)):
        np.take(lookup, centre + shift, out=by_entry[j])
    target = by_entry.T.ravel()
    values = np.empty((len(sample_pixel), psf.size))
    values[:] = psf.ravel()
    values = values.ravel()
    missing = np.flatnonzero(target < 0)
    values[missing] = 0.0
    target[missing] = 0
    indptr = np.arange(0, target.size + 1, psf.size)
    return sp.csr_matrix((values, target, indptr), shape=(len(sample_pixel), len(support_pixel)))


def _hull_corners(points) -> np.ndarray:
    """The corners of the convex hull of ``points`` (all of them where the hull is flat)."""
    try:
        return points[ConvexHull(points).vertices]
    except QhullError:
        return points


def _window(points, R, C, intrinsics: Intrinsics, height: int, width: int, pad: int):
    """The rows and columns, ``(v0, v1), (u0, u1)`` (ends excluded), of an image that hold the projection of
    ``points`` (body frame; the camera at ``C``, body to camera ``R``) with ``pad`` pixels around it, within the image
    (empty where it falls outside); the whole image where a point is not in front of the camera."""
    in_camera = (points - C) @ R.T
    if not np.all(in_camera[:, 2] > 0):
        return (0, height), (0, width)
    uv = project(in_camera, intrinsics)
    low, high = np.floor(uv.min(axis=0)).astype(int) - pad, np.ceil(uv.max(axis=0)).astype(int) + pad
    v0, u0 = max(low[1], 0), max(low[0], 0)
    return (v0, max(v0, min(high[1], height))), (u0, max(u0, min(high[0], width)))


def _cast(problem: _MeshProblem, h, light, rotations, centres, intrinsics: Intrinsics, images, variance, psf=None) -> _Samples:
    """Every lit, seen pixel ``margin`` pixels inside the silhouette and the cast shadows; under a PSF (``psf``,
    a normalised kernel) with every lit pixel that sees the surface and the blur from them to the samples."""
    import open3d as o3d

    settings = problem.settings
    P, _, _, _, cross, norm = problem.surface(h)
    n = cross / norm[:, None]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(P.astype(np.float32)), o3d.core.Tensor(problem.F.astype(np.uint32)))
    height, width = images[0].shape
    dirs_cam = pixel_rays_cam(intrinsics, *(axis.ravel() + 0.5 for axis in np.mgrid[0:height, 0:width][::-1]))
    kernel = np.ones((3, 3), bool)
    # A perspective view takes a convex set to a convex one: the surface's hull's corners bound its projection.
    corners = _hull_corners(P)
    parts, support = [], []
    for position, (R, C, image) in enumerate(zip(rotations, centres, images)):
        # Only the pixels of the surface's projected bounding box can see it: the rest of the image is not cast, and
        # the erosion's border (nothing seen) stands for it. The box has room for the erosion and float32's round-off.
        (v0, v1), (u0, u1) = _window(corners, R, C, intrinsics, height, width, pad=settings.margin + 2)
        if v1 == v0 or u1 == u0:
            continue
        vv, uu = (axis.ravel() for axis in np.mgrid[v0:v1, u0:u1])
        pixels = vv * width + uu
        d = (dirs_cam @ R)[pixels]  # turned whole, then cut: the same directions, to the bit, as the whole image's
        hit = scene.cast_rays(o3d.core.Tensor(np.hstack([np.broadcast_to(C, d.shape), d]).astype(np.float32)))
        t = hit["t_hit"].numpy()
        on = np.isfinite(t)
        face = np.where(on, hit["primitive_ids"].numpy().astype(np.int64), 0)
        light_body = R.T @ light
        cos_i = n[face] @ light_body
        cos_e = -np.einsum("ij,ij->i", n[face], d)
        lit = on & (cos_i > 0)
        lit_idx = np.flatnonzero(lit)
        X = C + t[lit_idx, None] * d[lit_idx]
        shadow_rays = np.hstack([X + SHADOW_OFFSET_PX * problem.footprint * n[face[lit_idx]], np.broadcast_to(light_body, (len(lit_idx), 3))])
        lit[lit_idx[np.isfinite(scene.cast_rays(o3d.core.Tensor(shadow_rays.astype(np.float32)))["t_hit"].numpy())]] = False
        box = (v1 - v0, u1 - u0)
        inside = binary_erosion(on.reshape(box), kernel, iterations=settings.margin) & binary_erosion(lit.reshape(box), kernel, iterations=settings.margin)
        value = image[vv, uu]
        keep = inside.ravel() & (cos_i >= settings.min_cos_incidence) & (cos_e >= settings.min_cos_emission) & (value > 0)
        parts.append((face[keep], np.full(int(keep.sum()), position), -d[keep], value[keep], position * height * width + pixels[keep]))
        if psf is not None:
            seen = np.flatnonzero(lit)
            support.append((face[seen], np.full(len(seen), position), -d[seen], position * height * width + pixels[seen]))
    if not parts:
        raise ValueError(f"the mesh shows only 0 usable pixels for {problem.n_par} unknowns: it projects into none of the {len(images)} images")
    face, image_pos, view, value, pixel = (np.concatenate(p) for p in zip(*parts))
    sigma = np.sqrt(variance(value) / value**2 + settings.floor**2)
    samples = _Samples(face, image_pos, view, np.log(value), sigma)
    cell = problem.cell[face]
    samples.columns = np.column_stack([
        problem.F[face], problem.o_a + cell, np.full(len(face), problem.o_k), problem.o_dk + cell,
        np.full(len(face), problem.o_l), np.full(len(face), problem.o_l + 1), problem.o_g + image_pos,
    ])
    if psf is not None:
        s_face, s_image, s_view, s_pixel = (np.concatenate(p) for p in zip(*support))
        samples.support = _Pixels(s_face, s_image, s_view)
        samples.blur = _blur_matrix(psf, pixel, s_pixel, (len(images), height, width))
    return samples


@dataclass
class _State:
    h: np.ndarray
    log_albedo: np.ndarray
    k: float
    dk: np.ndarray
    light: np.ndarray
    log_gains: np.ndarray

    def vector(self):
        return np.concatenate([self.h, self.log_albedo, [self.k], self.dk, [0.0, 0.0], self.log_gains])

    def stepped(self, problem: _MeshProblem, x) -> _State:
        e1, e2 = _light_basis(self.light)
        light = self.light + x[problem.o_l] * e1 + x[problem.o_l + 1] * e2
        return _State(
            self.h + x[: problem.nv], self.log_albedo + x[problem.o_a : problem.o_k], self.k + x[problem.o_k], self.dk + x[problem.o_dk : problem.o_l],
            light / np.linalg.norm(light), self.log_gains + x[problem.o_g :],
        )


def _shading(problem: _MeshProblem, state: _State, n, pixels: _Pixels | _Samples, rotations):
    """The log brightness the state gives each of ``pixels`` (face normals ``n``), whether both its cosines are above
    the clamp, and the parts the Jacobian needs."""
    light_body = np.einsum("nji,j->ni", rotations, state.light)[pixels.image]
    nf = n[pixels.face]
    cos_i = np.einsum("ij,ij->i", nf, light_body)
    cos_e = np.einsum("ij,ij->i", nf, pixels.view)
    ok = (cos_i > COS_CLAMP) & (cos_e > COS_CLAMP)
    cos_i, cos_e = np.maximum(cos_i, COS_CLAMP), np.maximum(cos_e, COS_CLAMP)
    cell = problem.cell[pixels.face]
    k = state.k + state.dk[cell]
    log_ie = np.log(cos_i) + np.log(cos_e)
    model = state.log_albedo[cell] + state.log_gains[pixels.image] + k * log_ie - np.log(cos_e)
    return model, ok, (nf, light_body, cos_i, cos_e, k, log_ie)


@dataclass
class _Evaluation:
    """The fit's residuals at one state (weighted, of the samples and of the priors) and what its Jacobian needs."""

    residuals: np.ndarray
    prior: np.ndarray
    weight: np.ndarray
    ok: np.ndarray
    corners: tuple  # the faces' corners a, b, c
    normals: np.ndarray  # unit face normals
    norm: np.ndarray  # their unnormalised lengths
    shading: tuple  # ``_shading``'s parts for the samples

    @property
    def cost(self) -> float:
        return 0.5 * (self.residuals @ self.residuals + self.prior @ self.prior)


def _evaluate(problem: _MeshProblem, samples: _Samples, state: _State, rotations) -> _Evaluation:
    """The weighted residuals of the samples and of the priors at ``state``.

    Under a PSF (``samples.blur``) a sample's model is the blurred brightness of the pixels around it."""
    settings = problem.settings
    _, a, b, c, cross, norm = problem.surface(state.h)
    n = cross / norm[:, None]
    model, ok, parts = _shading(problem, state, n, samples, rotations)
    if samples.blur is not None:
        model = np.log(samples.blur @ np.exp(_shading(problem, state, n, samples.support, rotations)[0]))
    r = np.where(ok, (samples.log_brightness - model) / samples.sigma, 0.0)
    weight = 1.0 / np.sqrt(1.0 + (r / settings.robust) ** 2) if settings.robust > 0 else np.ones_like(r)
    x_prior = np.concatenate([state.h, np.zeros(2 * problem.ncell + 3), state.log_gains])
    x_prior[problem.o_dk : problem.o_l] = state.dk
    return _Evaluation(r * weight, problem.prior @ x_prior, weight, ok, (a, b, c), n, norm, parts)


def _jacobian(problem: _MeshProblem, samples: _Samples, state: _State, evaluation: _Evaluation, rotations) -> sp.csr_matrix:
    """The samples' Jacobian (CSR, 9 per row) at ``state``, from its evaluation there (``_evaluate``).

    Under a PSF a sample's Jacobian is that of its own pixel's: the ratio of the blurred to the sharp value held
    within a step (the normal matrix keeps its size and sparsity). The exact gradient through the blur, with this
    matrix, stalled (docs/amica_record.md)."""
    s = np.where(evaluation.ok, -evaluation.weight / samples.sigma, 0.0)
    # d log-brightness / d normal, projected on the face's tangent plane and over |cross|: per face, the derivative of
    # the unit normal by each corner's height (the corner's normal D crossed with the opposite edge).
    D = problem.D
    Fv = problem.F
    a, b, c = evaluation.corners
    n, norm = evaluation.normals, evaluation.norm
    tangent = lambda v: (v - np.einsum("ij,ij->i", v, n)[:, None] * n) / norm[:, None]  # noqa: E731
    dn = np.stack([tangent(np.cross(D[Fv[:, 0]], b - c)), tangent(np.cross(D[Fv[:, 1]], c - a)), tangent(np.cross(b - a, D[Fv[:, 2]]))], axis=1)  # (nf, 3, 3)
    nf, light_body, cos_i, cos_e, k, log_ie = evaluation.shading
    g = (k / cos_i)[:, None] * light_body + ((k - 1) / cos_e)[:, None] * samples.view
    m = len(s)
    data = np.empty((m, 9))
    data[:, :3] = np.einsum("mj,mvj->mv", g, dn[samples.face]) * s[:, None]
    data[:, 3] = s
    data[:, 4] = s * log_ie
    data[:, 5] = s * log_ie
    e1, e2 = _light_basis(state.light)
    for j, e in enumerate((e1, e2)):
        e_body = np.einsum("nji,j->ni", rotations, e)[samples.image]
        data[:, 6 + j] = s * k * np.einsum("ij,ij->i", nf, e_body) / cos_i
    data[:, 8] = s
    return sp.csr_matrix((data.ravel(), samples.columns.ravel(), np.arange(0, 9 * m + 1, 9)), shape=(m, problem.n_par))


def _residuals(problem: _MeshProblem, samples: _Samples, state: _State, rotations, jacobian: bool):
    """Weighted residuals of the samples and of the priors; with ``jacobian`` the samples' Jacobian (``_jacobian``),
    else ``None``."""
    evaluation = _evaluate(problem, samples, state, rotations)
    return evaluation.residuals, evaluation.prior, _jacobian(problem, samples, state, evaluation, rotations) if jacobian else None


def fit_mesh_light(vertices, triangles, camera_centres: dict, body_to_camera: dict, intrinsics: Intrinsics, images, variance, start_light_cam, start_k: float,
                   gain_sigma: float, settings: MeshLightSettings = MeshLightSettings(), psf: np.ndarray | None = None) -> MeshLight:
    """The light of a shape from shading on the subdivided surface ``vertices``/``triangles`` (the cloud's Poisson surface).

    ``images``: the mission's images, already divided by any gains the start
    estimated, indexed as the poses' keys; ``variance``: a pixel value's
    noise variance (the sensor model), ``None`` for noise-free images (only
    ``settings.floor``); ``start_light_cam``, ``start_k``: where to start (the
    refinement's light and k); ``gain_sigma``: the mission's stated per-image
    calibration scatter (0: gains held at one); ``psf``: the camera's point spread function (a normalised kernel of
    odd side), by which the model is blurred, or ``None`` (no blur).
    """
    import open3d as o3d

    tick = time.perf_counter()
    indices = np.array(sorted(body_to_camera))
    rotations = np.array([body_to_camera[i][:3, :3] for i in indices])
    centres = np.array([camera_centres[i] for i in indices])
    used = [images[i] for i in indices]
    footprint = float(np.median(np.linalg.norm(centres - vertices.mean(axis=0), axis=1))) / intrinsics.focal_px
    edges = np.linalg.norm(vertices[triangles[:, 0]] - vertices[triangles[:, 1]], axis=1)
    n_sub = 0
    while np.median(edges) / 2**n_sub > settings.edge_px * footprint and n_sub < 4:
        n_sub += 1
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles)).subdivide_midpoint(number_of_iterations=n_sub)
    mesh.compute_vertex_normals()
    problem = _MeshProblem(np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).copy(), np.asarray(mesh.vertex_normals).copy(), footprint, len(indices), gain_sigma, settings)
    variance = variance if variance is not None else (lambda value: np.zeros_like(value))
    light = np.asarray(start_light_cam, float) / np.linalg.norm(start_light_cam)
    state = _State(np.zeros(problem.nv), np.zeros(problem.ncell), float(start_k), np.zeros(problem.ncell), light, np.zeros(len(indices)))
    log.info("mesh: %d vertices, %d faces (x%d), footprint %.3g, %d cells", problem.nv, len(problem.F), 4**n_sub, footprint, problem.ncell)
    damping, costs, steps, n_samples = settings.damping, [], 0, 0
    for outer in range(settings.outer):
        samples = _cast(problem, state.h, state.light, rotations, centres, intrinsics, used, variance, psf)
        n_samples = len(samples.face)
        if n_samples < problem.n_par:
            raise ValueError(f"the mesh shows only {n_samples} usable pixels for {problem.n_par} unknowns")
        if outer == 0:
            # The albedo starts at each cell's mean log residual.
            r = _evaluate(problem, samples, state, rotations).residuals
            cells = problem.cell[samples.face]
            counts = np.bincount(cells, minlength=problem.ncell)
            state.log_albedo = np.where(counts > 0, np.bincount(cells, weights=r * samples.sigma, minlength=problem.ncell) / np.maximum(counts, 1), 0.0)
        # The state's evaluation, kept from the step that accepted it.
        current = _evaluate(problem, samples, state, rotations)
        normal_matrix = _NormalMatrix(problem, samples)
        for _ in range(settings.inner):
            r, prior_r = current.residuals, current.prior
            J = _jacobian(problem, samples, state, current, rotations)
            cost = current.cost
            normal, colnorm = normal_matrix.scaled(J.data)
            gradient = -(J.T @ r + problem.prior.T @ prior_r) / colnorm
            del J
            for _attempt in range(MAX_ATTEMPTS):
                y = _solve(normal, gradient, damping, problem.order)
                trial = state.stepped(problem, y / colnorm)
                evaluation = _evaluate(problem, samples, trial, rotations)
                cost_new = evaluation.cost
                if cost_new < cost:
                    state, current, damping = trial, evaluation, max(damping / settings.damping_down, MIN_DAMPING)
                    costs.append(cost_new)
                    steps += 1
                    break
                damping *= 10
            log.info("cast %d: %d samples, cost %.5g, k %.4f, light %s (%.0f s)", outer, n_samples, costs[-1] if costs else cost, state.k, np.round(state.light, 5).tolist(), time.perf_counter() - tick)
    return MeshLight(state.light, float(state.k), state.log_gains, indices, n_samples, problem.nv, steps, np.array(costs), problem.surface(state.h)[0], problem.F)


class _NormalMatrix:
    """The normal matrix J'J + P'P of one cast's samples (Jacobian ``J``, priors ``P``), assembled at every step from
    the Jacobian's values on a pattern made once per cast.

    A sample's first ``FACE_SLOTS`` columns (``_Samples.columns``: its face's three heights, its cell's albedo, the
    body's k, its cell's k offset, the light's two angles) are fixed by its face, the last (its image's gain) by its
    image. So J'J is made of sums of products of a sample's values: for every face, of two of its first eight; for
    every column and image, of the gain's and that column's; for every image, of the gain's squares. Each is one
    ``bincount`` over the samples, and the sums go into the matrix's upper triangle through an index made once a cast,
    then mirrored. scipy's product of J' and J, which finds the pattern again at every step, took about four times as
    long (bench/bench_mesh_step.py)."""

    def __init__(self, problem: _MeshProblem, samples: _Samples):
        n, n_images = problem.n_par, problem.n_images
        self.n, self.n_images, self.image = n, n_images, samples.image
        self.face_of, first = _compact(samples.face, len(problem.F))
        face_columns = samples.columns[first, :FACE_SLOTS]
        self.n_faces = len(first)
        self.pairs = [(p, q) for p in range(FACE_SLOTS) for q in range(p, FACE_SLOTS)]
        # The gain's products with a column every sample shares (k, the light) are summed by image, the others by that
        # column and the image (``targets``: each sample's, numbered among those present).
        self.shared = [p for p in range(FACE_SLOTS) if np.all(face_columns[:, p] == face_columns[0, p])]
        self.by_target = [p for p in range(FACE_SLOTS) if p not in self.shared]
        self.targets, target_rows, target_gains = [], [], []
        for p in self.by_target:
            column = samples.columns[:, p]
            target, first = _compact(column * n_images + samples.image, n * n_images)
            self.targets.append((target, len(first)))
            target_rows.append(column[first])
            target_gains.append(problem.o_g + samples.image[first])
        images = problem.o_g + np.arange(n_images)
        prior = sp.triu(problem.prior_normal, format="coo")
        self.prior_values = np.concatenate([prior.data, np.zeros(n)])  # every diagonal entry stored, for the damping
        # Where each sum goes: its entry of the upper triangle, numbered part by part, then over all parts.
        parts = [*((face_columns[:, p], face_columns[:, q]) for p, q in self.pairs), *zip(target_rows, target_gains),
                 *((np.full(n_images, face_columns[0, p]), images) for p in self.shared), (images, images), (prior.row, prior.col),
                 (np.arange(n), np.arange(n))]
        keys, inverses = [], []
        for rows, cols in parts:
            part_keys, inverse = np.unique(np.minimum(rows, cols).astype(np.int64) * n + np.maximum(rows, cols), return_inverse=True)
            keys.append(part_keys)
            inverses.append(inverse.ravel())
        starts = np.cumsum([0, *(len(k) for k in keys[:-1])])
        keys, slot = np.unique(np.concatenate(keys), return_inverse=True)
        self.slot = np.concatenate([slot.ravel()[start + inverse] for start, inverse in zip(starts, inverses)])
        self.n_upper = len(keys)
        upper_row, upper_col = np.divmod(keys, n)
        # The whole matrix's pattern, each stored entry's value one more than the index of its upper-triangle sum (exact
        # in float64; none zero, which a sum of matrices would drop).
        upper = sp.csr_matrix((np.arange(1, self.n_upper + 1, dtype=float), upper_col, np.concatenate([[0], np.cumsum(np.bincount(upper_row, minlength=n))])), shape=(n, n))
        whole = (upper + sp.triu(upper, k=1, format="csr").T).tocsr()
        whole.sort_indices()
        self.source = whole.data.astype(np.int64) - 1
        self.col, self.indptr = whole.indices, whole.indptr
        self.row = np.repeat(np.arange(n), np.diff(whole.indptr))
        self.diagonal = np.flatnonzero(self.row == self.col)

    def __call__(self, jacobian_values) -> sp.csc_matrix:
        """The normal matrix at the Jacobian's values (its CSR ``data``, ``FACE_SLOTS + 1`` a sample), in CSC with every
        diagonal entry stored."""
        values = jacobian_values.reshape(-1, FACE_SLOTS + 1).T.copy()
        gain = values[FACE_SLOTS]
        sums = np.concatenate([
            *(np.bincount(self.face_of, values[p] * values[q], minlength=self.n_faces) for p, q in self.pairs),
            *(np.bincount(target, values[p] * gain, minlength=n_targets) for p, (target, n_targets) in zip(self.by_target, self.targets)),
            *(np.bincount(self.image, values[p] * gain, minlength=self.n_images) for p in self.shared),
            np.bincount(self.image, gain * gain, minlength=self.n_images), self.prior_values,
        ])
        data = np.bincount(self.slot, sums, minlength=self.n_upper)[self.source]
        # Symmetric: its rows' (CSR) arrays are its columns' (CSC).
        return sp.csc_matrix((data, self.col, self.indptr), shape=(self.n, self.n))

    def scaled(self, jacobian_values) -> tuple[sp.csc_matrix, np.ndarray]:
        """The normal matrix scaled by its columns' norms, S (J'J + P'P) S with S = diag(1 / norms), so that the damping
        treats every unknown alike; and the norms (1 for an empty column)."""
        normal = self(jacobian_values)
        norms = np.sqrt(normal.data[self.diagonal])
        norms[norms == 0] = 1.0
        normal.data /= norms[self.row] * norms[self.col]
        return normal, norms


def _solve(normal: sp.csc_matrix, gradient, damping: float, order: np.ndarray):
    """The damped step of the column-scaled system, (normal + damping I) y = gradient, by a sparse LU that eliminates
    the unknowns in ``order`` (a permutation of them).

    The LU is made in single precision, then the step is found in double precision by conjugate gradients with that LU
    as the preconditioner, to ``STEP_RTOL`` of the gradient (four to six iterations on the paper's sets). Should they
    not get there in ``STEP_MAX_ITERATIONS``, or the single precision factors be singular, the LU is made again in
    double precision."""
    damped = normal.copy()
    damped.setdiag(damped.diagonal() + damping)
    system, rhs = damped[order][:, order].tocsc(), gradient[order]
    x = _preconditioned_step(system, rhs)
    if x is None:
        log.info("the single precision LU's step missed %.0e in %d iterations, or its factors were singular: made in double precision", STEP_RTOL, STEP_MAX_ITERATIONS)
        x = _lu(system).solve(rhs)
    y = np.empty_like(gradient)
    y[order] = x
    return y


#: The mesh fit's step (``_solve``): the relative residual its conjugate gradients reach, and in how many iterations.
STEP_RTOL = 1e-12
STEP_MAX_ITERATIONS = 30


def _lu(system: sp.csc_matrix):
    # SuperLU's own orders: COLAMD's takes 1.8 to 3 times as long on the fit's surfaces; its minimum degree's is faster on
    # some, nine times slower on a regular mesh (docs/dropped.md). The matrix is symmetric and positive definite: no pivoting.
    return splu(system, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))


def _preconditioned_step(system: sp.csc_matrix, rhs: np.ndarray) -> np.ndarray | None:
    """``system``'s solution for ``rhs`` by conjugate gradients preconditioned by its single precision LU, or None where
    they do not converge or the single precision factors are singular (a pivot below its range). On a paper set's step
    (40,000 unknowns, 26 million entries in the factors) the single precision LU takes 1.0 s against 1.6 s, its values
    half the memory; the solution agrees with the double precision LU's to 5e-12."""
    try:
        lu = _lu(system.astype(np.float32))
    except RuntimeError:  # SuperLU: "Factor is exactly singular"
        return None
    preconditioner = LinearOperator(system.shape, lambda v: lu.solve(v.astype(np.float32)).astype(float), dtype=float)
    # Symmetric: its transpose (CSR, no copy) is itself.
    x, info = cg(system.T, rhs, rtol=STEP_RTOL, atol=0.0, maxiter=STEP_MAX_ITERATIONS, M=preconditioner)
    return x if info == 0 else None


def _dissection_order(points, edges, groups: sp.csr_matrix, leaf: int = 64) -> np.ndarray:
    """A nested dissection order of a surface's vertices (``points``, ``edges``: vertex pairs) and of groups of them (``groups``:
    a group by vertex incidence matrix), groups numbered after the vertices.

    The vertices are cut in two by the plane through their median along their widest extent; the separator is the
    vertices on one side with an edge to the other, and every group with vertices on both. Each half is ordered the same
    way, then the separator last, down to ``leaf`` nodes. On a surface the separators are curves, so the LU's fill grows
    about as n log n (scipy has no nested dissection; SuperLU's minimum degree orders are unreliable on regular meshes).
    """
    nv = len(points)
    adjacency = sp.csr_matrix((np.ones(2 * len(edges)), (edges.ravel(), edges[:, ::-1].ravel())), shape=(nv, nv))
    side = np.zeros(nv, np.int8)  # 1 and 2: the two halves of the current cut, 0 elsewhere

    def touching(matrix: sp.csr_matrix, rows, value):
        """Which of ``rows`` have a column whose side is ``value``."""
        sub = matrix[rows]
        hit = np.zeros(len(rows), bool)
        hit[np.repeat(np.arange(len(rows)), np.diff(sub.indptr))[side[sub.indices] == value]] = True
        return hit

    out = []

    def dissect(vertices, groups_here):
        if len(vertices) + len(groups_here) <= leaf or len(vertices) < 2:
            out.extend([vertices, nv + groups_here])
            return
        span = points[vertices].max(axis=0) - points[vertices].min(axis=0)
        coordinate = points[vertices, int(np.argmax(span))]
        first = coordinate < np.median(coordinate)
        if first.all() or not first.any():
            out.extend([vertices, nv + groups_here])
            return
        one, two = vertices[first], vertices[~first]
        side[one], side[two] = 1, 2
        in_one, in_two = touching(groups, groups_here, 1), touching(groups, groups_here, 2)
        separator = touching(adjacency, one, 2)
        side[vertices] = 0
        dissect(one[~separator], groups_here[~in_two])
        dissect(two, groups_here[in_two & ~in_one])
        out.extend([one[separator], nv + groups_here[in_one & in_two]])

    dissect(np.arange(nv), np.arange(groups.shape[0]))
    return np.concatenate(out).astype(np.int64)
