"""Helpers shared by the tests: light directions and per-point truths of synthetic sets, a sphere's exact image, a box."""

import numpy as np

from asteroid_photometry.reflectance import laws as photometry
from asteroid_photometry.world import cameras


def light_at(angle_deg, azimuth_deg=30.0):
    """Camera-frame light direction at a given light angle from -z."""
    theta, phi = np.radians(angle_deg), np.radians(azimuth_deg)
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)])


def per_point_truth(n_points, seed):
    """Per-point albedo in [0.3, 0.8] and k in [0.6, 1.0]."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.3, 0.8, n_points), rng.uniform(0.6, 1.0, n_points)


def sphere_image_closed_form(radiance_factor, light, radius_m, distance_m, image_size, fov_deg, supersample=6):
    """Pixel means, spreads and fully-lit interior of a sphere's image, from ray-sphere intersections on a sub-pixel grid.

    ``radiance_factor(cos_i, cos_o, cos_g)`` is the surface's law; the sphere
    sits ``distance_m`` down the optical axis of a square pinhole camera.
    """
    focal = 0.5 * image_size / np.tan(np.radians(fov_deg) / 2)
    intrinsics = cameras.Intrinsics(image_size, image_size, focal, image_size / 2, image_size / 2)
    offsets = (np.arange(supersample) + 0.5) / supersample
    pixel = np.arange(image_size)
    u = (pixel[None, :, None, None] + offsets[None, None, None, :]) * np.ones((image_size, 1, supersample, 1))
    v = (pixel[:, None, None, None] + offsets[None, None, :, None]) * np.ones((1, image_size, 1, supersample))
    d = cameras.pixel_rays_cam(intrinsics, u, v)
    centre = np.array([0.0, 0.0, distance_m])
    along = d @ centre
    disc = along**2 - (centre @ centre - radius_m**2)
    hit = disc > 0
    t = along - np.sqrt(np.where(hit, disc, 0.0))
    normal = (d * t[..., None] - centre) / radius_m
    cos_i, cos_o, cos_g = photometry.geometry_cosines(normal, light, -d)
    lit = hit & (cos_i > 0) & (cos_o > 0)
    b = np.where(lit, radiance_factor(cos_i, cos_o, cos_g), 0.0)
    interior = (lit & (cos_i > 0.2) & (cos_o > 0.2)).all(axis=(2, 3))
    return b.mean(axis=(2, 3)), b.std(axis=(2, 3)), interior


def equatorial_poses(n_images: int, distance: float) -> dict:
    """Cameras on a ring in the body's equator (z up), looking at the centre; OpenCV axes: body-to-camera 4x4 by index."""
    poses = {}
    for index in range(n_images):
        angle = 2 * np.pi * index / n_images
        centre = distance * np.array([np.cos(angle), np.sin(angle), 0.0])
        forward = -centre / distance
        down = np.array([0.0, 0.0, -1.0])
        right = np.cross(down, forward)
        rotation = np.stack([right, down, forward])
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rotation, -rotation @ centre
        poses[index] = pose
    return poses


#: The corners of a box centred on the origin (times its half extents) and its 12 facets, counter-clockwise seen from outside.
BOX_CORNERS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64)
BOX_FACES = np.array(
    [
        [0, 2, 1], [0, 3, 2],  # -z
        [4, 5, 6], [4, 6, 7],  # +z
        [0, 1, 5], [0, 5, 4],  # -y
        [3, 7, 6], [3, 6, 2],  # +y
        [0, 4, 7], [0, 7, 3],  # -x
        [1, 2, 6], [1, 6, 5],  # +x
    ],
    dtype=np.int64,
)
