"""Pose and frame conventions of the imaging geometry."""

import numpy as np
import pytest

from asteroid_photometry.world import cameras


@pytest.fixture
def geometry():
    return cameras.make_imaging_geometry(n_images=36, image_size=512, camera_distance_km=5.0, view_latitude_deg=0.0, body_radius_m=312.0)


def test_poses_are_rigid_and_camera_is_at_the_distance(geometry):
    rotations = geometry.body_to_camera[:, :3, :3]
    identity = np.einsum("nij,nkj->nik", rotations, rotations)
    assert np.allclose(identity, np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(rotations), 1.0)
    centres = cameras.camera_centres_body(geometry.body_to_camera)
    assert np.allclose(np.linalg.norm(centres, axis=1), 5000.0)


def test_body_centre_projects_to_principal_point(geometry):
    centre_cam = geometry.body_to_camera[:, :3, 3]
    uv = cameras.project(centre_cam, geometry.intrinsics)
    assert np.allclose(uv, [256.0, 256.0])


def test_body_turns_about_its_spin_axis_by_equal_steps(geometry):
    spin_axis_cam = geometry.body_to_camera[:, :3, :3] @ np.array([0.0, 0.0, 1.0])
    # The spin axis stays fixed in the camera frame and points up in the image (-y).
    assert np.allclose(spin_axis_cam, [0.0, -1.0, 0.0], atol=1e-12)
    relative = geometry.body_to_camera[1, :3, :3] @ geometry.body_to_camera[0, :3, :3].T
    step_deg = np.degrees(np.arccos((np.trace(relative) - 1) / 2))
    assert step_deg == pytest.approx(10.0)


def test_view_latitude_tilts_the_view(geometry):
    tilted = cameras.make_imaging_geometry(4, 64, 5.0, 30.0, 312.0)
    centre = cameras.camera_centres_body(tilted.body_to_camera[:1])[0]
    assert np.degrees(np.arcsin(centre[2] / np.linalg.norm(centre))) == pytest.approx(30.0)


def test_whole_body_fits_in_the_image(geometry):
    radius = 312.0
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(2000, 3))
    points = radius * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    for pose in geometry.body_to_camera[::6]:
        uv = cameras.project(points @ pose[:3, :3].T + pose[:3, 3], geometry.intrinsics)
        assert uv.min() > 0 and uv.max() < 512


def test_light_direction_angle_and_side():
    light = cameras.light_dir_cam(10.0)
    assert np.linalg.norm(light) == pytest.approx(1.0)
    assert np.degrees(np.arccos(-light[2])) == pytest.approx(10.0)
    assert light[0] > 0
    assert np.allclose(cameras.light_dir_cam(0.0), [0.0, 0.0, -1.0])


@pytest.mark.parametrize("angle_deg", [0.0, 10.0, 20.0, -7.5, 35.0])
def test_light_azimuth_zero_is_the_in_plane_light_bit_for_bit(angle_deg):
    angle = np.radians(angle_deg)
    in_plane = np.array([np.sin(angle), 0.0, -np.cos(angle)])
    for light in (cameras.light_dir_cam(angle_deg), cameras.light_dir_cam(angle_deg, 0.0), cameras.light_dir_cam(angle_deg, azimuth_deg=0)):
        assert light.tobytes() == in_plane.tobytes()


@pytest.mark.parametrize("azimuth_deg", [30.0, 90.0, -90.0, 180.0, 250.0])
def test_light_azimuth_turns_the_sun_about_the_optical_axis(azimuth_deg):
    light = cameras.light_dir_cam(20.0, azimuth_deg)
    assert np.linalg.norm(light) == pytest.approx(1.0)
    assert np.degrees(np.arccos(-light[2])) == pytest.approx(20.0)  # the phase angle is kept
    # Measured from +x towards +y (+y is down in the image).
    assert np.degrees(np.arctan2(light[1], light[0])) % 360.0 == pytest.approx(azimuth_deg % 360.0)
    assert np.allclose(cameras.light_dir_cam(20.0, azimuth_deg + 360.0), light)
    if azimuth_deg == 90.0:
        assert light[1] > 0.3 and abs(light[0]) < 1e-12


def test_pixel_rays_invert_projection(geometry):
    u, v = np.array([0.0, 100.5, 511.9]), np.array([3.0, 256.0, 400.25])
    rays = cameras.pixel_rays_cam(geometry.intrinsics, u, v)
    assert np.allclose(cameras.project(rays * 7.0, geometry.intrinsics), np.stack([u, v], axis=1))


def test_json_round_trip(geometry):
    again = cameras.ImagingGeometry.from_json(geometry.to_json())
    assert again.intrinsics == geometry.intrinsics
    assert np.allclose(again.body_to_camera, geometry.body_to_camera)


def test_camera_too_close_is_refused():
    with pytest.raises(ValueError, match="camera_distance_km"):
        cameras.make_imaging_geometry(4, 64, 0.4, 0.0, 312.0)
