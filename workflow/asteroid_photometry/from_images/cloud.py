"""From a sparse reconstruction to the estimator's input: an oriented point cloud that knows which images see it.

This is the CPU stand-in for PMVS's output (Table 2 of the paper): points,
outward normals and, per point, the images that see it, built from the
structure-from-motion model alone (no shape model, no true pose):

1. the triangulated points with tracks of at least ``min_track`` images;
2. outliers removed (open3d's statistical outlier removal: a point whose
   mean distance to its neighbours is far above the cloud's typical value);
3. normals by local plane fits (open3d ``estimate_normals``), turned to face
   the cameras of the point's track;
4. visibility: a point is seen by a registered image when it faces the
   camera (``cos_o >= min_cos_emission``) and a ray from the camera reaches
   it before any other surface, tested against a Poisson surface meshed from
   the cloud itself (open3d), so the set grows beyond the SIFT track;
5. brightness: the linear image sampled (bilinearly) at the point's
   projection through the reconstructed camera; with a ``purity_tolerance``
   only where the image itself shows the sample pure (``sample_pure``).

The result is an ``estimate.Observations`` in the reconstructed cameras'
frames, plus the point cloud for scoring after registration.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import map_coordinates

from asteroid_photometry.estimation import Observations
from asteroid_photometry.world.cameras import Intrinsics, project

log = logging.getLogger(__name__)


@dataclass
class OrientedCloud:
    points: np.ndarray  # (N, 3) reconstruction frame
    normals: np.ndarray  # (N, 3) unit, outward
    track_length: np.ndarray  # (N,) SIFT track length


def oriented_cloud(points, track_point, track_image, camera_centres: dict, min_track=3, outlier_neighbours=16, outlier_std=2.0, normal_neighbours=16) -> OrientedCloud:
    """Filter the sparse points and give them normals facing the cameras that saw them."""
    import open3d as o3d

    track_length = np.bincount(track_point, minlength=len(points))
    keep = np.flatnonzero(track_length >= min_track)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[keep]))
    _, inliers = cloud.remove_statistical_outlier(nb_neighbors=outlier_neighbours, std_ratio=outlier_std)
    keep = keep[np.asarray(inliers, dtype=int)]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[keep]))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=normal_neighbours))
    normals = np.asarray(cloud.normals)
    # Face the mean direction towards the track's cameras.
    centres = np.array([camera_centres[i] for i in track_image])
    towards = centres - points[track_point]
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    mean_towards = np.zeros_like(points)
    np.add.at(mean_towards, track_point, towards)
    flip = np.einsum("ij,ij->i", normals, mean_towards[keep]) < 0
    normals[flip] *= -1
    log.info("cloud: %d points with tracks >= %d, %d after outlier removal", int((track_length >= min_track).sum()), min_track, len(keep))
    return OrientedCloud(points[keep], normals, track_length[keep])


def poisson_surface(cloud: OrientedCloud, depth: int = 7):
    """A closed surface through the cloud, for occlusion tests: (vertices, triangles).

    Single-threaded: open3d's multi-threaded Poisson segfaults at random
    (isl-org/Open3D#6828; it killed one of 100 jobs of a full run here) and
    gives a slightly different mesh from call to call; one thread is fast
    enough for a few thousand points and makes the mesh reproducible.
    """
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.points))
    pcd.normals = o3d.utility.Vector3dVector(cloud.normals)
    mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=depth, n_threads=1)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def visible_pairs(cloud: OrientedCloud, body_to_camera: dict, min_cos_emission: float, occlusion_tolerance: float, surface=None):
    """(point, image) pairs where the point faces the camera and nothing hides it.

    ``surface``: (vertices, triangles) to test occlusion against; by default
    a Poisson surface of the cloud itself.
    """
    import open3d as o3d

    vertices, triangles = poisson_surface(cloud) if surface is None else surface
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    point_ids, image_ids = [], []
    for image, pose in body_to_camera.items():
        rotation, translation = pose[:3, :3], pose[:3, 3]
        centre = -rotation.T @ translation
        to_camera = centre - cloud.points
        distance = np.linalg.norm(to_camera, axis=1)
        facing = np.einsum("ij,ij->i", cloud.normals, to_camera) / distance >= min_cos_emission
        candidates = np.flatnonzero(facing)
        directions = -to_camera[candidates] / distance[candidates, None]
        rays = np.hstack([np.broadcast_to(centre, directions.shape), directions]).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        seen = hit >= distance[candidates] - occlusion_tolerance
        point_ids.append(candidates[seen])
        image_ids.append(np.full(int(seen.sum()), image))
    return np.concatenate(point_ids), np.concatenate(image_ids)


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """The image at continuous pixel positions (corner of the top-left pixel at (0, 0))."""
    return map_coordinates(image, [uv[:, 1] - 0.5, uv[:, 0] - 0.5], order=1, mode="constant", cval=0.0)


def sample_pure(image: np.ndarray, uv: np.ndarray, tolerance: float) -> np.ndarray:
    """The image at ``uv`` where the sample is pure by the image's own evidence, else 0.

    Pure: the four pixels a bilinear sample reads agree within ``tolerance``
    (relative to their mean). On a body of flat facets a pixel wholly on one
    facet has exactly that facet's brightness, while one straddling an edge,
    the limb or a shadow boundary takes a mixture that almost never equals
    its neighbours; four equal pixel centres on one facet enclose the sample
    (a triangle is convex), so it lies on that facet too. The tolerance must
    exceed the images' own scatter between pure pixels (rendering noise,
    sensor noise) and stay below the brightness step between neighbouring
    facets.
    """
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    height, width = image.shape
    col = np.clip(np.floor(x).astype(int), 0, width - 2)
    row = np.clip(np.floor(y).astype(int), 0, height - 2)
    support = np.stack([image[row, col], image[row, col + 1], image[row + 1, col], image[row + 1, col + 1]])
    mean = support.mean(axis=0)
    pure = (np.ptp(support, axis=0) <= tolerance * mean) & (support.min(axis=0) > 0)
    return np.where(pure, mean, 0.0)


def _pose_table(body_to_camera: dict) -> np.ndarray:
    """The body-to-camera matrices indexed by image id, (max id + 1, 4, 4); zeros where no image has that id."""
    table = np.zeros((max(body_to_camera, default=-1) + 1, 4, 4))
    for image, pose in body_to_camera.items():
        table[image] = pose
    return table


def poses_of(body_to_camera: dict, image_index) -> np.ndarray:
    """The body-to-camera matrix of every row's image, (n, 4, 4): one table lookup, no loop over rows."""
    return _pose_table(body_to_camera)[np.asarray(image_index, dtype=int)]


def rotations_of(body_to_camera: dict, image_index) -> np.ndarray:
    """The body-to-camera rotation of every row's image, (n, 3, 3), contiguous: :func:`poses_of`'s rotations without
    gathering the rest of each matrix (a sample array has up to millions of rows)."""
    return np.ascontiguousarray(_pose_table(body_to_camera)[:, :3, :3])[np.asarray(image_index, dtype=int)]


def rows_by_image(image_index) -> list[tuple[int, np.ndarray]]:
    """Each image that rows name, with its rows in ascending order: (image, rows) pairs, images ascending."""
    image_index = np.asarray(image_index, dtype=int)
    order = np.argsort(image_index, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(image_index[order])) + 1)
    return [(int(image_index[rows[0]]), rows) for rows in groups if len(rows)]


def in_cameras(vectors, image_index, body_to_camera: dict, *, translate: bool) -> np.ndarray:
    """Each row's vector (n, 3) in its image's camera frame: turned by the image's rotation, and moved by its
    translation where ``translate`` (points; not directions). Image by image, so no (n, 4, 4) array of poses is made."""
    vectors = np.asarray(vectors, dtype=float)
    out = np.empty_like(vectors)
    for image, rows in rows_by_image(image_index):
        pose = np.asarray(body_to_camera[image])
        out[rows] = np.einsum("ij,nj->ni", pose[:3, :3], vectors[rows])
        if translate:
            out[rows] += pose[:3, 3]
    return out


def default_occlusion_tolerance(points: np.ndarray) -> float:
    """How far behind the occluding surface a point may lie and still count as seen: 2 % of the cloud's extent."""
    return 0.02 * float(np.ptp(points, axis=0).max())


def sample_images(points, image_index, body_to_camera: dict, intrinsics: Intrinsics, images: list[np.ndarray], purity_tolerance=None):
    """Each point sampled in its image: (brightness, point in the camera frame, projection inside the image).

    ``points`` (n, 3) in the cameras' frame, ``image_index`` (n,) the image of
    each row. Bilinear samples, or with ``purity_tolerance`` only those
    ``sample_pure`` finds pure (0 elsewhere, and outside the image); a
    callable ``purity_tolerance(image, uv)`` is another purity test with
    ``sample_pure``'s contract (``purity.PurityTest``: the sensor's).
    """
    points_cam = in_cameras(points, image_index, body_to_camera, translate=True)
    uv = project(points_cam, intrinsics)
    inside = (uv[:, 0] >= 1) & (uv[:, 0] < intrinsics.width - 1) & (uv[:, 1] >= 1) & (uv[:, 1] < intrinsics.height - 1)
    brightness = np.zeros(len(points))
    for image, rows in rows_by_image(image_index):
        rows = rows[inside[rows]]
        if purity_tolerance is None:
            brightness[rows] = sample_bilinear(images[image], uv[rows])
        elif callable(purity_tolerance):
            brightness[rows] = purity_tolerance(images[image], uv[rows])
        else:
            brightness[rows] = sample_pure(images[image], uv[rows], purity_tolerance)
    return brightness, points_cam, inside


def cloud_observations(
    cloud: OrientedCloud, body_to_camera: dict, intrinsics: Intrinsics, images: list[np.ndarray], *,
    min_cos_emission: float = 0.1, min_observations: int = 4, occlusion_tolerance: float | None = None,
    purity_tolerance: float | None = None, surface=None,
) -> tuple[Observations, np.ndarray]:
    """The estimator's observations of the cloud; also returns the image index of every observation.

    ``purity_tolerance``: None samples bilinearly at every projection; a
    number keeps only the samples ``sample_pure`` finds pure. ``surface``:
    (vertices, triangles) for the occlusion test instead of the cloud's own
    Poisson surface.
    """
    if occlusion_tolerance is None:
        occlusion_tolerance = default_occlusion_tolerance(cloud.points)
    point_index, image_index = visible_pairs(cloud, body_to_camera, min_cos_emission, occlusion_tolerance, surface)
    brightness, points_cam, inside = sample_images(cloud.points[point_index], image_index, body_to_camera, intrinsics, images, purity_tolerance)
    normal_cam = in_cameras(cloud.normals[point_index], image_index, body_to_camera, translate=False)
    view_cam = -points_cam / np.linalg.norm(points_cam, axis=1, keepdims=True)
    keep = inside & (brightness > 0) & (np.einsum("ij,ij->i", normal_cam, view_cam) > 0)
    counts = np.bincount(point_index[keep], minlength=len(cloud.points))
    keep &= counts[point_index] >= min_observations
    log.info("cloud observations: %d visible pairs, %d kept on %d points", len(point_index), int(keep.sum()), int((counts >= min_observations).sum()))
    obs = Observations(point_index=point_index[keep], normal_cam=normal_cam[keep], view_cam=view_cam[keep], brightness=brightness[keep], n_points=len(cloud.points))
    return obs, image_index[keep]
