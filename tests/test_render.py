"""The Mitsuba Minnaert renderer against closed forms: a sphere, and a flat facet."""

import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from asteroid_photometry.world import cameras, observe, render
from synthetic_helpers import sphere_image_closed_form


@pytest.fixture(scope="module")
def variant():
    return render.setup_mitsuba("auto")


def closed_form_sphere(radius_m, distance_m, image_size, fov_deg, albedo, minnaert_k, light, supersample=6):
    """Pixel averages of the Minnaert sphere image (``synthetic_helpers.sphere_image_closed_form``)."""

    def minnaert(cos_i, cos_o, cos_g):
        return albedo * np.clip(cos_i, 1e-12, None) ** minnaert_k * np.clip(cos_o, 1e-12, None) ** (minnaert_k - 1)

    return sphere_image_closed_form(minnaert, light, radius_m, distance_m, image_size, fov_deg, supersample)


@pytest.mark.parametrize("light_deg, albedo, minnaert_k", [(0.0, 0.5, 0.7), (10.0, 0.7, 1.0), (30.0, 0.6, 0.85)])
def test_sphere_matches_closed_form(variant, light_deg, albedo, minnaert_k):
    light = cameras.light_dir_cam(light_deg)
    args = dict(radius_m=100.0, distance_m=5000.0, image_size=96, fov_deg=2.6)
    image = render.render_sphere(**args, albedo=albedo, minnaert_k=minnaert_k, light_dir_cam=light, spp=64)
    # (spp must match the value used below)
    spp = 64
    expected, spread, interior = closed_form_sphere(**args, albedo=albedo, minnaert_k=minnaert_k, light=light)
    assert interior.sum() > 2000
    difference = np.abs(image - expected)[interior]
    # Rendering noise: the pixel is the mean of spp random samples of a brightness
    # that varies across the pixel, so its error is about spread / sqrt(spp).
    z = difference / (spread[interior] / np.sqrt(spp) + 1e-7)
    assert np.mean(z) < 1.2  # 0.8 for Gaussian noise
    assert np.percentile(z, 99.9) < 6
    # The background and the unlit side are black (away from the lit pixels' edge).
    near_lit = binary_dilation(expected > 0, iterations=2)
    assert np.all(image[~near_lit] == 0)
    # The check can fail: a different k gives a clearly different image.
    wrong, _, _ = closed_form_sphere(**args, albedo=albedo, minnaert_k=minnaert_k - 0.1, light=light)
    assert np.abs(image - wrong)[interior].mean() > 20 * difference.mean()


@pytest.mark.parametrize("azimuth_deg, minnaert_k", [(60.0, 1.0), (-120.0, 0.8)])
def test_out_of_plane_light_lights_the_sphere_where_its_azimuth_says(variant, azimuth_deg, minnaert_k):
    """A Sun turned about the optical axis: the image matches the closed form and its bright side turns with it."""
    light = cameras.light_dir_cam(20.0, azimuth_deg)
    assert abs(light[1]) > 0.25  # well out of the camera's x-z plane
    args = dict(radius_m=100.0, distance_m=5000.0, image_size=96, fov_deg=2.6)
    spp, albedo = 64, 0.6
    image = render.render_sphere(**args, albedo=albedo, minnaert_k=minnaert_k, light_dir_cam=light, spp=spp)
    expected, spread, interior = closed_form_sphere(**args, albedo=albedo, minnaert_k=minnaert_k, light=light)
    assert interior.sum() > 2000
    difference = np.abs(image - expected)[interior]
    z = difference / (spread[interior] / np.sqrt(spp) + 1e-7)
    assert np.mean(z) < 1.2 and np.percentile(z, 99.9) < 6
    # The same Sun in the x-z plane, or mirrored across it, gives a clearly different image.
    for other in (cameras.light_dir_cam(20.0), light * [1.0, -1.0, 1.0]):
        wrong, _, _ = closed_form_sphere(**args, albedo=albedo, minnaert_k=minnaert_k, light=other)
        assert np.abs(image - wrong)[interior].mean() > 20 * difference.mean()
    # The image is mirror-symmetric about the line through its centre along the light's
    # azimuth, so the brightness centroid lies on it; +y (rows) is down in the image.
    rows, cols = np.indices(image.shape) + 0.5
    centre = args["image_size"] / 2
    u_mean, v_mean = (image * cols).sum() / image.sum() - centre, (image * rows).sum() / image.sum() - centre
    assert np.hypot(u_mean, v_mean) > 3.0
    assert np.degrees(np.angle(np.exp(1j * (np.arctan2(v_mean, u_mean) - np.radians(azimuth_deg))))) == pytest.approx(0.0, abs=1.0)
    if minnaert_k == 1.0:
        # Lambert: the brightest point is the subsolar point, at the sphere's radius along the light.
        focal = centre / np.tan(np.radians(args["fov_deg"]) / 2)
        subsolar = args["radius_m"] * light + [0.0, 0.0, args["distance_m"]]
        u_sun, v_sun = focal * subsolar[:2] / subsolar[2] + centre
        top = image >= np.quantile(image[image > 0], 0.99)
        assert np.hypot(cols[top].mean() - u_sun, rows[top].mean() - v_sun) < 1.0
        assert abs(v_sun - centre) > 8.0  # off the image's horizontal line through the centre


@pytest.mark.parametrize("azimuth_deg", [0.0, 70.0])
def test_flat_facets_are_exact_on_pure_pixels_and_images_are_not_mirrored(variant, tmp_path, azimuth_deg):
    """An off-axis tetrahedron: pure pixels hold exactly the Minnaert value, where our projection says.

    Also under a Sun out of the camera's x-z plane (azimuth 70 deg): the
    renderer and the observations' lit and shadow tests take any light.
    """
    vertices = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [0.0, 60.0, 0.0], [0.0, 0.0, 60.0]]) + [40.0, 25.0, -30.0]
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    tri = vertices[faces]
    centroids = tri.mean(axis=1)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    geometry = cameras.make_imaging_geometry(n_images=3, image_size=128, camera_distance_km=2.0, view_latitude_deg=20.0, body_radius_m=130.0)
    light = cameras.light_dir_cam(20.0, azimuth_deg)
    albedo, minnaert_k = 0.6, 0.75
    render.render_image_set(vertices, faces, geometry, albedo, minnaert_k, light, spp=8, out_dir=tmp_path)
    images = [render.read_image(tmp_path / f"image_{i:03d}.exr") for i in range(3)]
    obs = observe.observation_geometry(vertices, faces, centroids, normals, geometry, light, 0.05, 0.05, 1)
    assert len(obs.point_index) >= 5
    brightness = observe.sample_brightness(obs, images)
    cos_i = obs.normal_cam @ light
    cos_o = (obs.normal_cam * obs.view_cam).sum(axis=1)
    expected = albedo * cos_i**minnaert_k * cos_o ** (minnaert_k - 1)
    assert np.allclose(brightness, expected, rtol=1e-3)  # perspective varies cos_o across a pixel by ~1e-3
    # Every pure pixel of every lit facet, not only the one kept per facet and image.
    raycaster = observe.BodyRaycaster(vertices, faces)
    n_checked = 0
    for index, image in enumerate(images):
        corners = observe.corner_facet_ids(raycaster, geometry, index)
        top_left = corners[:-1, :-1]
        pure = (top_left >= 0) & (top_left == corners[1:, :-1]) & (top_left == corners[:-1, 1:]) & (top_left == corners[1:, 1:])
        rows, cols = np.nonzero(pure)
        normal_cam = normals[top_left[rows, cols]] @ geometry.body_to_camera[index, :3, :3].T
        view_cam = -cameras.pixel_rays_cam(geometry.intrinsics, cols + 0.5, rows + 0.5)
        cos_i, cos_o = normal_cam @ light, (normal_cam * view_cam).sum(axis=1)
        lit = (cos_i > 0.05) & (cos_o > 0.05)
        expected = albedo * cos_i[lit] ** minnaert_k * cos_o[lit] ** (minnaert_k - 1)
        assert np.allclose(image[rows[lit], cols[lit]], expected, rtol=1e-3)  # perspective varies cos_o across a pixel by ~1e-3
        n_checked += int(lit.sum())
    assert n_checked > 200
    # Every lit pixel lies inside the projected bounding box of the mesh, per image.
    for index, image in enumerate(images):
        pose = geometry.body_to_camera[index]
        uv = cameras.project(vertices @ pose[:3, :3].T + pose[:3, 3], geometry.intrinsics)
        rows, cols = np.nonzero(image > 0)
        assert cols.min() >= np.floor(uv[:, 0].min()) and cols.max() <= np.ceil(uv[:, 0].max())
        assert rows.min() >= np.floor(uv[:, 1].min()) and rows.max() <= np.ceil(uv[:, 1].max())


def test_unknown_variant_is_refused():
    with pytest.raises(RuntimeError, match="mitsuba_variant"):
        render.choose_variant("no_such_variant")


WRITE_AFTER_RENDER = """
import sys
import numpy as np
sys.path.insert(0, sys.argv[2])
from asteroid_photometry.world import render
render.setup_mitsuba("llvm_ad_rgb")
render.set_render_threads(int(sys.argv[1]))
import mitsuba as mi
image = render.render_sphere(1000.0, 5000.0, 32, 30.0, 0.5, 0.8, np.array([0.0, 0.0, -1.0]), 2)
mi.Bitmap(np.asarray(image, dtype=np.float32)[..., None]).write(sys.argv[3])
print("written")
"""


def test_a_render_job_given_one_core_still_writes_its_images(tmp_path):
    """``snakemake --cores 1`` gives the render job one thread: with Dr.Jit's pool at one, writing the EXR hung."""
    import subprocess
    import sys
    from pathlib import Path

    if not render.variant_works("llvm_ad_rgb"):
        pytest.skip("llvm_ad_rgb is not usable here")
    workflow = str(Path(__file__).resolve().parents[1] / "workflow")
    run = subprocess.run(
        [sys.executable, "-c", WRITE_AFTER_RENDER, "1", workflow, str(tmp_path / "sphere.exr")], capture_output=True, text=True, timeout=120,
    )
    assert run.returncode == 0 and "written" in run.stdout, run.stderr[-2000:]
    assert render.read_image(tmp_path / "sphere.exr").max() > 0
