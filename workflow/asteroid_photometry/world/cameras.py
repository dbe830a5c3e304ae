"""Imaging geometry: camera intrinsics, per-image poses of the turning body, the Sun.

The camera and the Sun are fixed; the body turns about its spin axis (+z of
the body frame) through its centre, ``360 / n_images`` degrees between
images. The camera sits at ``view_latitude_deg`` above the body's equator,
``camera_distance_km`` from the centre, with the projected spin axis pointing
up in the image. The Sun lies ``light_angle_deg`` from the direction towards
the camera (the phase angle); by default in the camera's x-z plane on the +x
side, and ``light_dir_cam``'s ``azimuth_deg`` turns it about the optical axis
out of that plane; ``tilted_light_dir_cam`` tilts it out of that plane by a
given angle, keeping its projection on the plane at the set's light angle.

Conventions are those of :mod:`asteroid_photometry` (OpenCV camera frame,
metres, continuous pixel coordinates with the image corner at 0).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from asteroid_photometry.world import cameras


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; square pixels, no distortion."""

    width: int
    height: int
    focal_px: float
    cx: float
    cy: float

    @property
    def matrix(self) -> np.ndarray:
        return np.array([[self.focal_px, 0.0, self.cx], [0.0, self.focal_px, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_x_deg(self) -> float:
        return float(np.degrees(2.0 * np.arctan(0.5 * self.width / self.focal_px)))

    def to_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "focal_px": self.focal_px, "cx": self.cx, "cy": self.cy}


def intrinsics_for_body(image_size: int, camera_distance_m: float, body_radius_m: float, margin: float = 1.08) -> Intrinsics:
    """Intrinsics whose field of view holds the whole body in any rotation.

    ``body_radius_m`` is the largest distance of a vertex from the body
    centre; the nearest point of the body can be that much closer than the
    centre, hence the ``camera_distance_m - body_radius_m`` below.
    """
    if camera_distance_m <= 1.5 * body_radius_m:
        raise ValueError(
            f"config key 'camera_distance_km': {camera_distance_m / 1000:g} km is too close for a body "
            f"of radius {body_radius_m / 1000:.3f} km (need more than 1.5 radii)"
        )
    tan_half_fov = margin * body_radius_m / (camera_distance_m - body_radius_m)
    focal_px = 0.5 * image_size / tan_half_fov
    return Intrinsics(image_size, image_size, float(focal_px), image_size / 2.0, image_size / 2.0)


def rotation_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def inertial_to_camera_rotation(view_latitude_deg: float) -> np.ndarray:
    """Rotation from the inertial frame (the body frame at image 0) to the camera frame."""
    lat = np.radians(view_latitude_deg)
    towards_camera = np.array([np.cos(lat), 0.0, np.sin(lat)])
    z_cam = -towards_camera
    spin_axis = np.array([0.0, 0.0, 1.0])
    up = spin_axis - np.dot(spin_axis, z_cam) * z_cam
    y_cam = -up / np.linalg.norm(up)
    x_cam = np.cross(y_cam, z_cam)
    return np.vstack([x_cam, y_cam, z_cam])


def body_to_camera_poses(n_images: int, camera_distance_m: float, view_latitude_deg: float = 0.0) -> np.ndarray:
    """4x4 body-to-camera matrices, shape (n_images, 4, 4); image i has turned 360 i / n_images degrees."""
    view = inertial_to_camera_rotation(view_latitude_deg)
    poses = np.tile(np.eye(4), (n_images, 1, 1))
    for i in range(n_images):
        poses[i, :3, :3] = view @ rotation_z(2.0 * np.pi * i / n_images)
        poses[i, :3, 3] = (0.0, 0.0, camera_distance_m)
    return poses


def camera_centres_body(body_to_camera: np.ndarray) -> np.ndarray:
    """Camera centres in the body frame, shape (n, 3): ``-R^T t`` per image."""
    rotation = body_to_camera[..., :3, :3]
    translation = body_to_camera[..., :3, 3]
    return -np.einsum("nji,nj->ni", rotation, translation)


def simulate_navigation_positions(body_to_camera: np.ndarray, sigma_m: float, seed=0) -> np.ndarray:
    """A simulated navigation solution: the true camera centres in the body frame plus N(0, sigma_m^2) per axis, (n, 3) metres.

    What a mission knows of where its camera was; the world stage that writes
    a mission's files draws it from the true poses, nothing downstream does.
    ``seed``: anything ``numpy.random.default_rng`` takes (the workflow's: the
    configured seed, the set's and the condition's).
    """
    true_centres = camera_centres_body(np.asarray(body_to_camera, dtype=float))
    rng = np.random.default_rng(seed)
    return true_centres + rng.normal(0.0, sigma_m, size=true_centres.shape)


def light_dir_cam(light_angle_deg: float, azimuth_deg: float = 0.0) -> np.ndarray:
    """Unit vector towards the Sun in the camera frame, ``light_angle_deg`` from ``-z``.

    ``azimuth_deg`` is the turn about the optical axis from ``+x`` towards
    ``+y``: 0 puts the Sun in the x-z plane on the +x side (image right), 90
    on the +y side, which is down in the image (towards the body's southern
    hemisphere: the spin axis points up). Azimuth 0 is computed exactly as
    the in-plane light always was, so existing sets keep their bits.
    """
    angle = np.radians(light_angle_deg)
    if azimuth_deg == 0.0:
        return np.array([np.sin(angle), 0.0, -np.cos(angle)])
    azimuth = np.radians(azimuth_deg)
    return np.array([np.sin(angle) * np.cos(azimuth), np.sin(angle) * np.sin(azimuth), -np.cos(angle)])


def tilted_light_dir_cam(light_angle_deg: float, out_of_plane_deg: float = 0.0) -> np.ndarray:
    """The Sun ``light_angle_deg`` from ``-z`` in the camera's x-z plane, then tilted ``out_of_plane_deg`` out of it.

    The unit vector ``(sin a cos e, sin e, -cos a cos e)``: its angle out of
    the x-z plane is ``e`` (towards ``+y``, down in the image, for positive
    ``e``) and its projection on that plane lies ``a`` from ``-z``, the
    set's own light angle; the phase angle is ``arccos(cos a cos e)``.
    ``out_of_plane_deg == 0`` is :func:`light_dir_cam` itself, bit for bit.
    """
    if out_of_plane_deg == 0.0:
        return light_dir_cam(light_angle_deg)
    angle, tilt = np.radians(light_angle_deg), np.radians(out_of_plane_deg)
    return np.array([np.sin(angle) * np.cos(tilt), np.sin(tilt), -np.cos(angle) * np.cos(tilt)])


def project(points_cam: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Continuous pixel coordinates (u, v) of camera-frame points, shape (..., 2)."""
    z = points_cam[..., 2]
    u = intrinsics.focal_px * points_cam[..., 0] / z + intrinsics.cx
    v = intrinsics.focal_px * points_cam[..., 1] / z + intrinsics.cy
    return np.stack([u, v], axis=-1)


def pixel_rays_cam(intrinsics: Intrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Unit ray directions in the camera frame through continuous pixel positions (u, v)."""
    directions = np.stack(
        [(u - intrinsics.cx) / intrinsics.focal_px, (v - intrinsics.cy) / intrinsics.focal_px, np.ones_like(u, dtype=float)],
        axis=-1,
    )
    return directions / np.linalg.norm(directions, axis=-1, keepdims=True)


@dataclass(frozen=True)
class ImagingGeometry:
    """Everything about the images but the surface: intrinsics and one pose per image."""

    intrinsics: Intrinsics
    body_to_camera: np.ndarray  # (n_images, 4, 4)
    camera_distance_m: float
    view_latitude_deg: float

    @property
    def n_images(self) -> int:
        return len(self.body_to_camera)

    def to_json(self) -> str:
        return json.dumps(
            {
                "intrinsics": self.intrinsics.to_dict(),
                "camera_distance_m": self.camera_distance_m,
                "view_latitude_deg": self.view_latitude_deg,
                "images": [
                    {
                        "index": i,
                        "rotation_deg": 360.0 * i / self.n_images,
                        "body_to_camera": pose.tolist(),
                        "camera_centre_body_m": centre.tolist(),
                    }
                    for i, (pose, centre) in enumerate(zip(self.body_to_camera, camera_centres_body(self.body_to_camera)))
                ],
            },
            indent=1,
        )

    @classmethod
    def from_json(cls, text: str) -> "ImagingGeometry":
        data = json.loads(text)
        return cls(
            intrinsics=Intrinsics(**data["intrinsics"]),
            body_to_camera=np.array([image["body_to_camera"] for image in data["images"]], dtype=float),
            camera_distance_m=float(data["camera_distance_m"]),
            view_latitude_deg=float(data["view_latitude_deg"]),
        )


def make_imaging_geometry(n_images: int, image_size: int, camera_distance_km: float, view_latitude_deg: float, body_radius_m: float) -> ImagingGeometry:
    distance_m = camera_distance_km * 1000.0
    return ImagingGeometry(
        intrinsics=intrinsics_for_body(image_size, distance_m, body_radius_m),
        body_to_camera=body_to_camera_poses(n_images, distance_m, view_latitude_deg),
        camera_distance_m=distance_m,
        view_latitude_deg=view_latitude_deg,
    )


def load_imaging_geometry(path) -> cameras.ImagingGeometry:
    return cameras.ImagingGeometry.from_json(Path(path).read_text())
