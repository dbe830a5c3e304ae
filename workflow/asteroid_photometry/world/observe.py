"""Observations on the true geometry: which surface points each image sees, and how bright.

The point cloud is the shape model's facets: one point per facet at its
centroid, with the facet's outward normal, which is exactly the normal the
renderer shaded that facet with (flat facets, no vertex normals).

An observation of point p in image i is kept only when the pixel it is
sampled from is *pure*: lit by the Sun, seen by the camera, and covered
entirely by p's own facet. Mixed pixels, where a pixel straddles the limb,
a facet edge, the terminator or a shadow edge, average different surfaces
and are the main error source of this kind of experiment; a pure pixel's
value is exactly the Minnaert brightness of its facet. The tests, all by
ray casting with open3d on the body-frame mesh:

- coverage: rays through the four corners of the pixel that contains the
  centroid's projection all hit p's facet first. A projected triangle is
  convex, so the whole pixel then lies on the facet (an occluder smaller than
  a pixel that touches none of its corners could slip through; at the
  default 1.2 m pixels and 4.7 m facets none does);
- lit, with no cast shadow: rays from the centroid and from points near the
  three vertices towards the Sun all escape;
- not grazing: ``cos_i >= min_cos_incidence`` and ``cos_o >= min_cos_emission``.

With ``pixel_selection: projection`` the pixel is instead the one that
contains the centroid's projection, whenever the ray through its centre
hits the facet, mixed or not, as the paper did; it exists to measure what
mixed pixels cost (docs/method.md, "Mixed and pure pixels").

The geometry of the observations (which point, which pixel, the normal and
view direction in the camera frame) depends on the light only through the
shadows, so it is computed once per light angle and shared by the sets.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from asteroid_photometry.core import files
from asteroid_photometry.world.cameras import camera_centres_body, ImagingGeometry, pixel_rays_cam, project

log = logging.getLogger(__name__)

# Start shadow rays this far off the surface (metres) so they don't hit their own facet.
SHADOW_RAY_OFFSET_M = 1e-2
# Shadow rays near the vertices start this fraction of the way towards the centroid.
VERTEX_INSET = 0.02


@dataclass
class ObservationGeometry:
    """Where each kept observation is: arrays of length n_obs, sorted by point."""

    point_index: np.ndarray  # (n_obs,) int64, facet / point id
    image_index: np.ndarray  # (n_obs,) int64
    pixel_row: np.ndarray  # (n_obs,) int64
    pixel_col: np.ndarray  # (n_obs,) int64
    normal_cam: np.ndarray  # (n_obs, 3) unit normal in the image's camera frame
    view_cam: np.ndarray  # (n_obs, 3) unit vector point -> camera, camera frame
    n_points: int

    def save(self, path) -> None:
        files.savez(path, **{name: getattr(self, name) for name in self.__dataclass_fields__})

    @classmethod
    def load(cls, path) -> "ObservationGeometry":
        with np.load(path) as data:
            return cls(**{name: data[name] for name in cls.__dataclass_fields__})


class BodyRaycaster:
    """open3d ray casting against the body-frame mesh."""

    def __init__(self, vertices_m: np.ndarray, faces: np.ndarray):
        import open3d as o3d

        self._o3d = o3d
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(vertices_m, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
        )

    def _rays(self, origins: np.ndarray, directions: np.ndarray):
        origins = np.broadcast_to(origins, directions.shape)
        rays = np.concatenate([origins, directions], axis=-1).astype(np.float32)
        return self._o3d.core.Tensor(np.ascontiguousarray(rays))

    def first_hit_facet(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Index of the first facet hit by each ray, -1 for a miss; shape of ``directions[..., 0]``."""
        hits = self.scene.cast_rays(self._rays(origins, directions))
        ids = hits["primitive_ids"].numpy().astype(np.int64)
        ids[~np.isfinite(hits["t_hit"].numpy())] = -1
        return ids

    def occluded(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Whether each ray hits the body at all."""
        return self.scene.test_occlusions(self._rays(origins, directions)).numpy().astype(bool)


def corner_facet_ids(raycaster: BodyRaycaster, geometry: ImagingGeometry, image: int) -> np.ndarray:
    """First facet hit through every pixel corner of ``image``: shape (height + 1, width + 1)."""
    intrinsics = geometry.intrinsics
    u, v = np.meshgrid(np.arange(intrinsics.width + 1, dtype=float), np.arange(intrinsics.height + 1, dtype=float))
    directions_cam = pixel_rays_cam(intrinsics, u, v)
    rotation = geometry.body_to_camera[image, :3, :3]
    directions_body = directions_cam @ rotation  # R^T d for each ray
    centre_body = camera_centres_body(geometry.body_to_camera[image : image + 1])[0]
    return raycaster.first_hit_facet(centre_body, directions_body)


def nearest_pure_pixels(raycaster: BodyRaycaster, geometry: ImagingGeometry, image: int, centroids_m: np.ndarray):
    """For every facet with a pure pixel in ``image``: the pure pixel nearest its centroid's projection.

    A pixel is pure when the rays through its four corners all hit the same
    facet first. Returns ``(facets, rows, cols)``.
    """
    corners = corner_facet_ids(raycaster, geometry, image)
    top_left = corners[:-1, :-1]
    pure = (top_left >= 0) & (top_left == corners[:-1, 1:]) & (top_left == corners[1:, :-1]) & (top_left == corners[1:, 1:])
    rows, cols = np.nonzero(pure)
    facets = top_left[rows, cols]
    pose = geometry.body_to_camera[image]
    uv = project(centroids_m[facets] @ pose[:3, :3].T + pose[:3, 3], geometry.intrinsics)
    distance2 = (cols + 0.5 - uv[:, 0]) ** 2 + (rows + 0.5 - uv[:, 1]) ** 2
    order = np.lexsort((distance2, facets))
    first = np.unique(facets[order], return_index=True)[1]
    chosen = order[first]
    return facets[chosen], rows[chosen], cols[chosen]


def projection_pixels(raycaster: BodyRaycaster, geometry: ImagingGeometry, image: int, centroids_m: np.ndarray):
    """For every facet visible at its centroid's projection: that pixel, pure or mixed (the paper's way).

    A facet counts as visible when the ray through the centre of the pixel
    containing its centroid's projection hits it first. Returns ``(facets, rows, cols)``.
    """
    intrinsics = geometry.intrinsics
    pose = geometry.body_to_camera[image]
    uv = project(centroids_m @ pose[:3, :3].T + pose[:3, 3], intrinsics)
    cols, rows = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
    inside = (cols >= 0) & (cols < intrinsics.width) & (rows >= 0) & (rows < intrinsics.height)
    facets = np.flatnonzero(inside)
    directions_body = pixel_rays_cam(intrinsics, cols[facets] + 0.5, rows[facets] + 0.5) @ pose[:3, :3]
    centre_body = camera_centres_body(geometry.body_to_camera[image : image + 1])[0]
    seen = raycaster.first_hit_facet(centre_body, directions_body) == facets
    return facets[seen], rows[facets[seen]], cols[facets[seen]]


PIXEL_SELECTIONS = {"pure": nearest_pure_pixels, "projection": projection_pixels}


def facet_unshadowed(raycaster: BodyRaycaster, vertices_m, faces, centroids_m, normals, facets, light_dir_body) -> np.ndarray:
    """Whether ``facets`` are entirely in sunlight: no cast shadow at the centroid or near the vertices."""
    corners = vertices_m[faces[facets]]  # (n, 3, 3)
    centroids = centroids_m[facets][:, None, :]
    starts = np.concatenate([centroids, corners + VERTEX_INSET * (centroids - corners)], axis=1)  # (n, 4, 3)
    starts = starts + SHADOW_RAY_OFFSET_M * normals[facets][:, None, :]
    directions = np.broadcast_to(light_dir_body, starts.shape)
    return ~raycaster.occluded(starts, directions).any(axis=1)


def pixel_footprint_unshadowed(raycaster: BodyRaycaster, geometry: ImagingGeometry, image: int, rows, cols, facet_points, facet_normals, light_dir_body) -> np.ndarray:
    """Whether the surface seen through each pixel's four corners and centre is in sunlight.

    ``facet_points`` and ``facet_normals`` (n, 3) give the plane of the facet
    each pixel sees (pure pixels: all five rays hit that facet). A facet can be
    lit at its centroid and near its vertices and still carry a sliver of cast
    shadow; at 1024 pixels 20 such pixels of 373,519 (brightness 6 to 42 %
    low) made the light error up to 0.002 deg instead of 1e-5, and the
    per-point k RMSE 9e-4 instead of 1e-5. This tests the pixel itself.
    """
    centre_body = camera_centres_body(geometry.body_to_camera[image : image + 1])[0]
    rotation = geometry.body_to_camera[image, :3, :3]
    offsets = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0], [0.5, 0.5]])
    u = cols[:, None] + offsets[None, :, 0]
    v = rows[:, None] + offsets[None, :, 1]
    directions = pixel_rays_cam(geometry.intrinsics, u, v) @ rotation  # (n, 5, 3) body frame
    # Where each ray meets the facet's plane; then a shadow ray from just above it.
    depth = np.einsum("nj,nj->n", facet_normals, facet_points - centre_body)[:, None] / np.einsum("nj,nkj->nk", facet_normals, directions)
    starts = centre_body + depth[..., None] * directions + SHADOW_RAY_OFFSET_M * facet_normals[:, None, :]
    return ~raycaster.occluded(starts, np.broadcast_to(light_dir_body, starts.shape)).any(axis=1)


def observation_geometry(
    vertices_m: np.ndarray,
    faces: np.ndarray,
    centroids_m: np.ndarray,
    normals: np.ndarray,
    geometry: ImagingGeometry,
    light_dir_cam: np.ndarray,
    min_cos_incidence: float = 0.1,
    min_cos_emission: float = 0.1,
    min_observations_per_point: int = 4,
    pixel_selection: str = "pure",
) -> ObservationGeometry:
    """The observations of every facet centroid in every image (see module docstring).

    ``pixel_selection`` is ``pure`` (the default, exact) or ``projection``
    (the pixel of the centroid's projection, mixed or not).
    """
    if pixel_selection not in PIXEL_SELECTIONS:
        raise ValueError(f"config key 'observations.pixel_selection': {pixel_selection!r} is not one of {sorted(PIXEL_SELECTIONS)}")
    select_pixels = PIXEL_SELECTIONS[pixel_selection]
    raycaster = BodyRaycaster(vertices_m, faces)
    intrinsics = geometry.intrinsics
    n_facets = len(faces)
    kept = {name: [] for name in ("point_index", "image_index", "pixel_row", "pixel_col", "normal_cam", "view_cam")}
    counts = dict(selected=0, facing=0, lit=0)
    for image, pose in enumerate(geometry.body_to_camera):
        rotation, translation = pose[:3, :3], pose[:3, 3]
        facets, row, col = select_pixels(raycaster, geometry, image, centroids_m)
        counts["selected"] += len(facets)
        normals_cam = normals[facets] @ rotation.T
        if pixel_selection == "pure":
            # The pixel averages the facet over its footprint: its view direction is that of its centre.
            view_cam = -pixel_rays_cam(intrinsics, col + 0.5, row + 0.5)
        else:
            centroids_cam = centroids_m[facets] @ rotation.T + translation
            view_cam = -centroids_cam / np.linalg.norm(centroids_cam, axis=1, keepdims=True)
        cos_emission = np.einsum("ij,ij->i", normals_cam, view_cam)
        cos_incidence = normals_cam @ light_dir_cam
        candidate = (cos_emission >= min_cos_emission) & (cos_incidence >= min_cos_incidence)
        counts["facing"] += int(candidate.sum())
        light_dir_body = rotation.T @ light_dir_cam
        candidate[candidate] = facet_unshadowed(raycaster, vertices_m, faces, centroids_m, normals, facets[candidate], light_dir_body)
        if pixel_selection == "pure":
            lit = facets[candidate]
            candidate[candidate] = pixel_footprint_unshadowed(
                raycaster, geometry, image, row[candidate], col[candidate], centroids_m[lit], normals[lit], light_dir_body,
            )
        counts["lit"] += int(candidate.sum())

        kept["point_index"].append(facets[candidate])
        kept["image_index"].append(np.full(int(candidate.sum()), image, dtype=np.int64))
        kept["pixel_row"].append(row[candidate])
        kept["pixel_col"].append(col[candidate])
        kept["normal_cam"].append(normals_cam[candidate])
        kept["view_cam"].append(view_cam[candidate])

    arrays = {name: np.concatenate(parts) for name, parts in kept.items()}
    per_point = np.bincount(arrays["point_index"], minlength=n_facets)
    enough = per_point[arrays["point_index"]] >= min_observations_per_point
    order = np.argsort(arrays["point_index"][enough], kind="stable")
    arrays = {name: values[enough][order] for name, values in arrays.items()}
    log.info(
        "observations over %d images: %d (facet, image) pairs with a %s pixel, %d of them facing camera and Sun "
        "(cos >= thresholds), %d without cast shadow, "
        "%d kept on %d points with >= %d observations",
        geometry.n_images, counts["selected"], pixel_selection, counts["facing"], counts["lit"], len(arrays["point_index"]),
        int((per_point >= min_observations_per_point).sum()), min_observations_per_point,
    )
    return ObservationGeometry(n_points=n_facets, **arrays)


def sample_brightness(geometry_obs: ObservationGeometry, images: list[np.ndarray]) -> np.ndarray:
    """The rendered brightness of every observation: image ``image_index`` at its pixel."""
    stack = np.stack(images)
    return stack[geometry_obs.image_index, geometry_obs.pixel_row, geometry_obs.pixel_col]
