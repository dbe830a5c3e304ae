"""Geometry of a triangle mesh: distances to it, samples of it, its axes and size, and similarity transforms."""

from __future__ import annotations

import numpy as np

from asteroid_photometry.world.shape import facet_geometry


def similarity_transform(scale: float, rotation, translation) -> np.ndarray:
    """The 4x4 matrix of ``x -> scale * rotation @ x + translation``."""
    transform = np.eye(4)
    transform[:3, :3] = scale * np.asarray(rotation, dtype=np.float64)
    transform[:3, 3] = np.asarray(translation, dtype=np.float64)
    return transform



def decompose_similarity(transform) -> tuple[float, np.ndarray, np.ndarray]:
    """(scale, rotation (3,3), translation (3,)) of a 4x4 similarity (no reflection)."""
    transform = np.asarray(transform, dtype=np.float64)
    linear = transform[:3, :3]
    scale = float(np.cbrt(np.linalg.det(linear)))
    if not scale > 0:
        raise ValueError(f"not a similarity without reflection: determinant {np.linalg.det(linear):.3g}")
    # The nearest rotation to linear / scale (exact for a true similarity).
    u, _, vt = np.linalg.svd(linear / scale)
    rotation = u @ vt
    return scale, rotation, transform[:3, 3].copy()



def transform_points(transform, points) -> np.ndarray:
    """Points (N,3) mapped by a 4x4 transform."""
    transform = np.asarray(transform, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]



def transform_normals(transform, normals) -> np.ndarray:
    """Unit normals (N,3) turned by the rotation of a 4x4 similarity (scale and translation ignored)."""
    _, rotation, _ = decompose_similarity(transform)
    return np.asarray(normals, dtype=np.float64) @ rotation.T



def rotation_angle_deg(rotation_a, rotation_b) -> float:
    """Angle in degrees of the rotation that takes ``rotation_b`` to ``rotation_a``."""
    relative = np.asarray(rotation_a) @ np.asarray(rotation_b).T
    return float(np.degrees(np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0))))



def _as_points(points, name="points") -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {points.shape}")
    return points



def _as_mesh(vertices_m, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices_m = _as_points(vertices_m, "vertices_m")
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces must have shape (F, 3) with F > 0, got {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices_m):
        raise ValueError(f"face indices must lie in [0, {len(vertices_m)}) (0-based)")
    return vertices_m, faces



class SurfaceQuery:
    """Distances and closest facets of points to one triangle mesh (open3d ``RaycastingScene``).

    Build once, query many times. The scene holds float32 coordinates, so
    the mesh is shifted to its vertex centroid first (queries are shifted
    the same way): precision then depends on the body's size, not on where
    it sits. Distances are unsigned, in the mesh's length unit.
    """

    def __init__(self, vertices, faces):
        import open3d as o3d

        vertices, faces = _as_mesh(vertices, faces)
        self.offset = vertices[np.unique(faces)].mean(axis=0)
        self.n_faces = len(faces)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices - self.offset, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
        )

    def _query_tensor(self, points):
        import open3d as o3d

        points = _as_points(points)
        return o3d.core.Tensor(np.ascontiguousarray(points - self.offset, dtype=np.float32))

    def distance(self, points) -> np.ndarray:
        """Unsigned distance (N,) from each point to the surface."""
        if len(points) == 0:
            return np.zeros(0)
        return self._scene.compute_distance(self._query_tensor(points)).numpy().astype(np.float64)

    def closest(self, points) -> tuple[np.ndarray, np.ndarray]:
        """(closest surface points (N,3), their facet ids (N,) int64)."""
        if len(points) == 0:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
        answer = self._scene.compute_closest_points(self._query_tensor(points))
        closest_points = answer["points"].numpy().astype(np.float64) + self.offset
        return closest_points, answer["primitive_ids"].numpy().astype(np.int64)



def point_to_surface_distance(points, vertices_m, faces) -> np.ndarray:
    """Unsigned distance in metres (N,) from each body-frame point to the mesh surface."""
    return SurfaceQuery(vertices_m, faces).distance(points)



def closest_facet(points, vertices_m, faces) -> np.ndarray:
    """Index (N,) int64 into ``faces`` of the facet nearest to each body-frame point.

    Use it to score a reconstructed point against its true facet's albedo,
    Minnaert k and normal (``facet_geometry(vertices_m, faces)[1][ids]``).
    """
    return SurfaceQuery(vertices_m, faces).closest(points)[1]



def sample_surface(vertices_m, faces, n_points: int, seed=0) -> tuple[np.ndarray, np.ndarray]:
    """``n_points`` points uniformly distributed over the mesh surface, and the facet of each.

    Facets are drawn with probability proportional to their area, points
    uniformly inside them. Returns (points (n,3) in the mesh's frame and
    unit, facet ids (n,) int64). ``seed`` is an int or a numpy Generator.
    """
    vertices_m, faces = _as_mesh(vertices_m, faces)
    rng = np.random.default_rng(seed)
    corners = vertices_m[faces]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    facet_ids = rng.choice(len(faces), size=int(n_points), p=areas / areas.sum())
    u, v = rng.random((2, int(n_points)))
    outside = u + v > 1.0
    u[outside], v[outside] = 1.0 - u[outside], 1.0 - v[outside]
    chosen = corners[facet_ids]
    points = chosen[:, 0] + u[:, None] * (chosen[:, 1] - chosen[:, 0]) + v[:, None] * (chosen[:, 2] - chosen[:, 0])
    return points, facet_ids.astype(np.int64)



def principal_axes(vertices_m, faces) -> tuple[np.ndarray, np.ndarray]:
    """(area-weighted surface centroid (3,), principal axes (3,3) as columns, longest first), body frame."""
    vertices_m, faces = _as_mesh(vertices_m, faces)
    corners = vertices_m[faces]
    _, _, areas = facet_geometry(vertices_m, faces)
    weights = areas / areas.sum()
    centroid = weights @ corners.mean(axis=1)
    # Second moment of the surface about the centroid, exact for triangles:
    # the mean of x x^T over a triangle (a, b, c) is (a a^T + b b^T + c c^T + s s^T) / 12, s = a + b + c.
    offsets = corners - centroid
    sums = offsets.sum(axis=1)
    moment = np.einsum("f,fci,fcj->ij", weights, offsets, offsets) + np.einsum("f,fi,fj->ij", weights, sums, sums)
    moment /= 12.0
    eigenvalues, axes = np.linalg.eigh(moment)
    axes = axes[:, np.argsort(eigenvalues)[::-1]]
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return centroid, axes



def body_length_m(vertices_m, faces) -> float:
    """The body's longest extent: the vertices' range along the surface's first principal axis.

    Frame-independent (unlike a bounding box); for Itokawa's models it is
    the long-axis length, about 560 m (Gaskell) or 548 m (Ostro).
    """
    vertices_m, faces = _as_mesh(vertices_m, faces)
    centroid, axes = principal_axes(vertices_m, faces)
    used = vertices_m[np.unique(faces)]
    along = (used - centroid) @ axes
    return float((along.max(axis=0) - along.min(axis=0)).max())
