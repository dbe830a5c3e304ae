"""Relief below the shape model's resolution: a finer mesh whose facets tilt off their shape-model facet.

A rendered shape-model facet is flat, so every pure pixel on it sees the
same normal and, but for perspective, the same brightness. Real surfaces
have relief below any shape model's resolution. :func:`relief_mesh` builds
a finer mesh for the renderer:

1. every facet is split ``levels`` times by midpoint subdivision (each
   triangle into four, through its edge midpoints; a midpoint is shared by
   the two facets of its edge, so the mesh stays closed), giving
   ``4**levels`` children per facet, listed together in the facet's order;
2. every new vertex moves along its local normal (its shape-model facet's
   normal, or the area-weighted mean of the two facets' on a shared edge)
   by ``A * (h(x) - H(x))``: ``h`` is a smooth Gaussian random field of the
   flat vertex position ``x`` (``surface_maps.smooth_random_field``:
   squared-exponential correlation of length ``correlation_length_m``, a
   sum of random cosine waves drawn from ``seed``), and ``H`` its linear
   interpolation between the facet's corners. The shape model's own
   vertices stay where they are, the displacement is continuous across
   edges, and what is left is relief within a facet, not a tilt of the
   whole facet. A slender facet gets less (its shortest altitude over the
   model's median one, at most 1, the smallest of a vertex's facets): the
   same heights over its short altitude would tilt its children steeply,
   some of the shipped Itokawa model's until they folded over;
3. the amplitude ``A`` is set so that the RMS slope of the fine faces (the
   angle between a fine face's normal and its shape-model facet's normal,
   weighted by the face's area before displacement) is ``rms_slope_deg``:
   a first amplitude from the slope of a tiny trial relief, where the slope
   is linear in ``A``, then a few rescalings by requested over achieved
   slope.

``parent_facet[i]`` is the shape-model facet that fine face ``i`` came from:
per-facet albedo and k go to the fine mesh as ``values[parent_facet]``
(``render.render_image_set``'s ``parent_facet`` does it), and observations
and scores stay on the shape model's facets.

The subdivision is numpy (edges made unique with ``np.unique``): open3d's
``subdivide_midpoint`` gives no map from the new triangles to the old ones,
and the order of its output is its own.
"""

from __future__ import annotations

import numpy as np

from asteroid_photometry.world.shape import facet_geometry
from asteroid_photometry.world.surface_maps import smooth_random_field

__all__ = ["relief_mesh", "subdivide", "facet_slopes_deg", "achieved_rms_slope_deg"]

# Random cosine waves summed into the relief field (surface_maps.smooth_random_field's features).
N_WAVES = 128
# The amplitude is rescaled until the achieved RMS slope is within this fraction of the request.
_SLOPE_TOLERANCE = 1e-4
_MAX_RESCALINGS = 20


def _check_levels(levels) -> int:
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise ValueError(f"relief levels must be a non-negative integer, got {levels!r}")
    return int(levels)


def _subdivide_with_edges(vertices_m, faces, levels):
    """``subdivide``, and per level the (new vertex ids, (n, 2) endpoint ids) of the midpoints it added."""
    vertices = np.array(vertices_m, dtype=np.float64)
    faces = np.array(faces, dtype=np.int64)
    parent = np.arange(len(faces), dtype=np.int64)
    added = []
    for _ in range(levels):
        # Edges (a, b), (b, c), (c, a) of every face; one midpoint per undirected edge.
        edges = np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1).reshape(-1, 2)
        unique, edge_id = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
        first_new = len(vertices)
        vertices = np.vstack([vertices, 0.5 * (vertices[unique[:, 0]] + vertices[unique[:, 1]])])
        added.append((first_new + np.arange(len(unique), dtype=np.int64), unique))
        mid = first_new + edge_id.reshape(-1, 3)  # midpoints of (ab, bc, ca)
        a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
        ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
        # Four children, each wound as its parent.
        faces = np.stack(
            [np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)], axis=1
        ).reshape(-1, 3)
        parent = np.repeat(parent, 4)
    return vertices, faces, parent, added


def subdivide(vertices_m, faces, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoint subdivision, ``levels`` times: ``(vertices, faces, parent_facet)`` of the flat finer mesh.

    The input vertices come first, unchanged; each level appends one
    midpoint per edge. Facet ``f``'s ``4**levels`` children are faces
    ``f * 4**levels`` to ``(f + 1) * 4**levels - 1``, wound as ``f``.
    """
    vertices, faces, parent, _ = _subdivide_with_edges(vertices_m, faces, _check_levels(levels))
    return vertices, faces, parent


def facet_slopes_deg(vertices_m, faces, parent_facet, parent_normals) -> np.ndarray:
    """Angle in degrees between each face's normal and its parent facet's unit normal."""
    _, normals, _ = facet_geometry(vertices_m, faces)
    reference = np.asarray(parent_normals, dtype=np.float64)[np.asarray(parent_facet)]
    cross = np.linalg.norm(np.cross(normals, reference), axis=1)
    return np.degrees(np.arctan2(cross, np.einsum("ij,ij->i", normals, reference)))


def achieved_rms_slope_deg(vertices_m, faces, parent_facet, parent_normals, weights=None) -> float:
    """RMS of :func:`facet_slopes_deg`, weighted by ``weights`` (the faces' areas when None)."""
    slopes = facet_slopes_deg(vertices_m, faces, parent_facet, parent_normals)
    if weights is None:
        weights = facet_geometry(vertices_m, faces)[2]
    return float(np.sqrt(np.sum(weights * slopes**2) / np.sum(weights)))


def relief_mesh(
    vertices_m,
    faces,
    levels: int = 2,
    rms_slope_deg: float = 3.0,
    seed: int = 0,
    correlation_length_m: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A finer mesh with smooth random relief: ``(vertices, faces, parent_facet)`` (module docstring).

    ``levels`` subdivisions (4**levels faces per facet); the relief's RMS
    slope against the parent facets is ``rms_slope_deg`` (area-weighted),
    its correlation length ``correlation_length_m`` (default: the shape
    model's mean edge length), drawn from ``seed``. ``levels == 0`` or
    ``rms_slope_deg == 0`` returns the input (as float64 vertices, int64
    faces) with ``parent_facet = arange``: without new vertices there is
    nothing to displace, and a flat subdivision (``subdivide``) renders as
    its input.
    """
    levels = _check_levels(levels)
    rms_slope = float(rms_slope_deg)
    if not np.isfinite(rms_slope) or not 0.0 <= rms_slope < 45.0:
        raise ValueError(f"relief rms_slope_deg must be in [0, 45), got {rms_slope_deg!r}")
    vertices_in = np.array(vertices_m, dtype=np.float64)
    faces_in = np.array(faces, dtype=np.int64)
    if vertices_in.ndim != 2 or vertices_in.shape[1] != 3 or faces_in.ndim != 2 or faces_in.shape[1] != 3:
        raise ValueError(f"relief_mesh needs (V, 3) vertices and (F, 3) faces, got {vertices_in.shape} and {faces_in.shape}")
    if levels == 0 or rms_slope == 0.0:
        return vertices_in, faces_in, np.arange(len(faces_in), dtype=np.int64)

    _, parent_normals, parent_areas = facet_geometry(vertices_in, faces_in)
    corners = vertices_in[faces_in]
    if correlation_length_m is None:
        correlation_length_m = float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).mean())
    if not np.isfinite(correlation_length_m) or correlation_length_m <= 0.0:
        raise ValueError(f"relief correlation_length_m must be positive, got {correlation_length_m!r}")

    flat, fine_faces, parent, added = _subdivide_with_edges(vertices_in, faces_in, levels)
    n_original = len(vertices_in)

    # The relief: the field less its linear interpolation between each facet's corners
    # (the interpolation of a midpoint is the mean of its edge's two ends, level by level).
    field = smooth_random_field(flat, correlation_length_m, np.random.default_rng(seed), n_features=N_WAVES)
    interpolated = field.copy()
    for new, ends in added:
        interpolated[new] = 0.5 * (interpolated[ends[:, 0]] + interpolated[ends[:, 1]])
    relief = field - interpolated
    relief[:n_original] = 0.0
    # Less relief on slender facets: the same height over a short altitude would tilt
    # (even fold) their children far more. Each new vertex takes the smallest weight of the
    # facets it lies on: the facet's shortest altitude over the median one, at most 1.
    altitude = 2.0 * parent_areas / np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    facet_weight = np.minimum(1.0, altitude / np.median(altitude))
    vertex_weight = np.ones(len(flat))
    for corner in range(3):
        np.minimum.at(vertex_weight, fine_faces[:, corner], facet_weight[parent])
    relief *= vertex_weight

    # Local normals of the new vertices: the area-weighted mean of the normals of the facets they lie on.
    vertex_normals = np.zeros_like(flat)
    contribution = parent_normals[parent] * parent_areas[parent, None]
    for corner in range(3):
        np.add.at(vertex_normals, fine_faces[:, corner], contribution)
    length = np.linalg.norm(vertex_normals, axis=1, keepdims=True)
    vertex_normals = np.divide(vertex_normals, length, out=np.zeros_like(vertex_normals), where=length > 0)
    direction = relief[:, None] * vertex_normals

    # Every child of a facet has a quarter of its parent's area at each level: weigh by the parent's.
    weights = parent_areas[parent]

    def achieved(amplitude):
        return achieved_rms_slope_deg(flat + amplitude * direction, fine_faces, parent, parent_normals, weights)

    # A tiny trial relief fixes the slope per unit amplitude, then rescale until on target.
    trial = 1e-6 * correlation_length_m
    slope_trial = achieved(trial)
    if not slope_trial > 0.0:
        raise ValueError("relief_mesh: the relief has no slope (degenerate mesh?)")
    amplitude = trial * rms_slope / slope_trial
    for _ in range(_MAX_RESCALINGS):
        slope = achieved(amplitude)
        if abs(slope / rms_slope - 1.0) <= _SLOPE_TOLERANCE:
            break
        amplitude *= rms_slope / slope
    else:
        raise ValueError(f"relief_mesh: could not reach an RMS slope of {rms_slope:g} deg (last {slope:.4g} deg); ask for less")
    return flat + amplitude * direction, fine_faces, parent

