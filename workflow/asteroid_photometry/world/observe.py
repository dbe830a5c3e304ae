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
  three vertices towards the Sun all escape, and (pure pixels) rays from
  where the pixel's corners and centre meet the facet;
- not grazing: ``cos_i >= min_cos_incidence`` and ``cos_o >= min_cos_emission``.

With ``pixel_selection: projection`` the pixel is instead the one that
contains the centroid's projection, whenever the ray through its centre
hits the facet, mixed or not, as the paper did; it exists to measure what
mixed pixels cost (docs/method.md, "Mixed and pure pixels").

The tests split in two. What needs no light (coverage, ``cos_o``) gives the
*candidates*, :func:`candidate_geometry`: once per imaging geometry, shared
by the sets. What needs the light (``cos_i`` and the cast shadows) is
:class:`LitTest`, a mask over the candidates for whatever light it is
given; the workflow gives it the light estimated from the set's own images
(``estimation.selection``), never the true one. :func:`dark_floor` says
which samples an image itself shows dark, for the first selection, made
before any light is known.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from asteroid_photometry.core import files
from asteroid_photometry.world import noise
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
            arrays = {name: data[name] for name in cls.__dataclass_fields__}
        return cls(**dict(arrays, n_points=int(arrays["n_points"])))

    def subset(self, rows) -> "ObservationGeometry":
        """The observations ``rows`` (a boolean mask or indices), in that order."""
        return ObservationGeometry(n_points=self.n_points, **{
            name: getattr(self, name)[rows] for name in self.__dataclass_fields__ if name != "n_points"
        })


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


def candidate_geometry(
    vertices_m: np.ndarray,
    faces: np.ndarray,
    centroids_m: np.ndarray,
    normals: np.ndarray,
    geometry: ImagingGeometry,
    min_cos_emission: float = 0.1,
    min_observations_per_point: int = 4,
    pixel_selection: str = "pure",
) -> ObservationGeometry:
    """The observations that need no light: every facet seen on its pixel, facing the camera.

    Visibility, the pixel (``pixel_selection``: ``pure``, the default and
    exact, or ``projection``, the pixel of the centroid's projection, mixed
    or not) and the emission cut; points seen fewer than
    ``min_observations_per_point`` times are left out (no light can give
    them more). The light's part, the incidence cut and the cast shadows,
    is :class:`LitTest`'s.
    """
    if pixel_selection not in PIXEL_SELECTIONS:
        raise ValueError(f"config key 'observations.pixel_selection': {pixel_selection!r} is not one of {sorted(PIXEL_SELECTIONS)}")
    select_pixels = PIXEL_SELECTIONS[pixel_selection]
    raycaster = BodyRaycaster(vertices_m, faces)
    intrinsics = geometry.intrinsics
    kept = {name: [] for name in ("point_index", "image_index", "pixel_row", "pixel_col", "normal_cam", "view_cam")}
    n_selected = 0
    for image, pose in enumerate(geometry.body_to_camera):
        rotation, translation = pose[:3, :3], pose[:3, 3]
        facets, row, col = select_pixels(raycaster, geometry, image, centroids_m)
        n_selected += len(facets)
        normals_cam = normals[facets] @ rotation.T
        if pixel_selection == "pure":
            # The pixel averages the facet over its footprint: its view direction is that of its centre.
            view_cam = -pixel_rays_cam(intrinsics, col + 0.5, row + 0.5)
        else:
            centroids_cam = centroids_m[facets] @ rotation.T + translation
            view_cam = -centroids_cam / np.linalg.norm(centroids_cam, axis=1, keepdims=True)
        facing = np.einsum("ij,ij->i", normals_cam, view_cam) >= min_cos_emission
        for name, values in (("point_index", facets), ("image_index", np.full(len(facets), image, dtype=np.int64)),
                             ("pixel_row", row), ("pixel_col", col), ("normal_cam", normals_cam), ("view_cam", view_cam)):
            kept[name].append(values[facing])
    arrays = {name: np.concatenate(parts) for name, parts in kept.items()}
    candidates = ObservationGeometry(n_points=len(faces), **arrays)
    enough = enough_observations(candidates.point_index, np.ones(len(candidates.point_index), bool), len(faces), min_observations_per_point)
    order = np.argsort(candidates.point_index[enough], kind="stable")
    candidates = candidates.subset(np.flatnonzero(enough)[order])
    log.info(
        "candidate observations over %d images: %d (facet, image) pairs with a %s pixel, %d facing the camera "
        "(cos_o >= %g), %d on %d points seen >= %d times",
        geometry.n_images, n_selected, pixel_selection, len(arrays["point_index"]), min_cos_emission,
        len(candidates.point_index), len(np.unique(candidates.point_index)), min_observations_per_point,
    )
    return candidates


def enough_observations(point_index: np.ndarray, mask: np.ndarray, n_points: int, min_observations_per_point: int) -> np.ndarray:
    """``mask`` less the rows of points it keeps fewer than ``min_observations_per_point`` times."""
    per_point = np.bincount(point_index[mask], minlength=n_points)
    return mask & (per_point[point_index] >= min_observations_per_point)


class LitTest:
    """The light's part of the selection: which candidate observations a given light direction lights.

    A candidate is lit when ``cos_i >= min_cos_incidence`` and its facet
    carries no cast shadow (shadow rays from the centroid and near the three
    vertices escape) and, for pure pixels, neither does the pixel's own
    footprint on the facet (rays from where its corners and centre meet the
    facet escape). The light is whatever the caller passes: an estimate
    made from the images for the observations the estimators see.
    """

    def __init__(self, vertices_m, faces, centroids_m, normals, geometry: ImagingGeometry, candidates: ObservationGeometry,
                 min_cos_incidence: float = 0.1, pixel_selection: str = "pure"):
        self.raycaster = BodyRaycaster(vertices_m, faces)
        self.vertices_m, self.faces, self.centroids_m, self.normals = vertices_m, faces, centroids_m, normals
        self.geometry, self.candidates = geometry, candidates
        self.min_cos_incidence, self.pixel_selection = min_cos_incidence, pixel_selection

    def __call__(self, light_dir_cam) -> np.ndarray:
        """Boolean mask over the candidates: lit by ``light_dir_cam`` (camera frame, unit vector towards the Sun)."""
        light_dir_cam = np.asarray(light_dir_cam, dtype=float)
        light_dir_cam = light_dir_cam / np.linalg.norm(light_dir_cam)
        cand = self.candidates
        lit = cand.normal_cam @ light_dir_cam >= self.min_cos_incidence
        for image in np.unique(cand.image_index[lit]):
            rows = np.flatnonzero(lit & (cand.image_index == image))
            light_dir_body = self.geometry.body_to_camera[image, :3, :3].T @ light_dir_cam
            facets = cand.point_index[rows]
            ok = facet_unshadowed(self.raycaster, self.vertices_m, self.faces, self.centroids_m, self.normals, facets, light_dir_body)
            if self.pixel_selection == "pure":
                rows_ok = rows[ok]
                ok[ok] = pixel_footprint_unshadowed(
                    self.raycaster, self.geometry, int(image), cand.pixel_row[rows_ok], cand.pixel_col[rows_ok],
                    self.centroids_m[facets[ok]], self.normals[facets[ok]], light_dir_body,
                )
            lit[rows] = ok
        return lit


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
    """The observations of every facet centroid in every image under a known light (see module docstring).

    :func:`candidate_geometry` and then :class:`LitTest` with
    ``light_dir_cam``. The workflow's observations are selected with a light
    estimated from the images instead (``estimation.selection``); this
    one-step form serves the tests and the experiments that hold the light.
    """
    candidates = candidate_geometry(vertices_m, faces, centroids_m, normals, geometry, min_cos_emission, min_observations_per_point, pixel_selection)
    lit = LitTest(vertices_m, faces, centroids_m, normals, geometry, candidates, min_cos_incidence, pixel_selection)(light_dir_cam)
    keep = enough_observations(candidates.point_index, lit, candidates.n_points, min_observations_per_point)
    log.info("%d of %d candidate observations lit and unshadowed, %d kept", int(lit.sum()), len(lit), int(keep.sum()))
    return candidates.subset(keep)


#: A sample is dark at or below this fraction of the samples' 99th percentile of brightness (and, in a noisy
#: image, at or below ``noise.dark_level``). The lit samples the incidence cut keeps are far brighter:
#: ``albedo cos_i**k cos_o**(k - 1) >= albedo min_cos_incidence**k``, 0.05 at albedo 0.5, k 1, cos_i 0.1,
#: against about 0.006 for the default sets' floor.
DARK_FRACTION = 0.01


def dark_floor(brightness: np.ndarray, sensor=None) -> float:
    """The brightness at or below which a sample counts as dark: in cast shadow or turned from the Sun.

    Known from the image alone: a relative floor, :data:`DARK_FRACTION` of
    the 99th percentile of ``brightness``, and with a ``sensor``
    (``noise.SensorModel``) at least the level a dark pixel's own noise
    stays below (``noise.dark_level``).
    """
    floor = DARK_FRACTION * float(np.percentile(brightness, 99)) if len(brightness) else 0.0
    if sensor is not None:
        floor = max(floor, noise.dark_level(sensor))
    return floor


def sample_brightness(geometry_obs: ObservationGeometry, images: list[np.ndarray]) -> np.ndarray:
    """The rendered brightness of every observation: image ``image_index`` at its pixel."""
    stack = np.stack(images)
    return stack[geometry_obs.image_index, geometry_obs.pixel_row, geometry_obs.pixel_col]
