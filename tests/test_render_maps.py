"""Per-facet albedo and k in the renderer: every pure pixel holds its own facet's Minnaert value."""

import json

import numpy as np
import open3d as o3d
import pytest

from asteroid_photometry.world import cameras, observe, render, surface_maps

ALBEDO, MINNAERT_K = 0.6, 0.8


@pytest.fixture(scope="module")
def variant():
    return render.setup_mitsuba("auto")


@pytest.fixture(scope="module")
def faceted_body():
    """A coarse, slightly squashed sphere: a few dozen flat facets, each a few hundred pixels."""
    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=60.0, resolution=5)
    vertices = np.asarray(mesh.vertices) * [1.0, 0.8, 0.7] + [5.0, -3.0, 2.0]
    faces = np.asarray(mesh.triangles)
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    geometry = cameras.make_imaging_geometry(n_images=3, image_size=128, camera_distance_km=1.0, view_latitude_deg=25.0, body_radius_m=70.0)
    return vertices, faces, tri.mean(axis=1), normals, geometry


@pytest.fixture(scope="module")
def maps(faceted_body):
    """Strongly varying per-facet values: facets differ far beyond the test's tolerance."""
    _, faces, centroids, _, _ = faceted_body
    spec = {"kind": "random_field", "albedo_contrast": 0.3, "k_contrast": 0.2, "correlation_length_m": 15.0}
    return surface_maps.facet_maps(centroids, spec, seed=5, albedo=ALBEDO, minnaert_k=MINNAERT_K)


def pure_pixel_facets(faceted_body, index):
    """(rows, cols, facet) of every pure pixel of image ``index`` and its facet's normal in the camera frame."""
    vertices, faces, _, normals, geometry = faceted_body
    corners = observe.corner_facet_ids(observe.BodyRaycaster(vertices, faces), geometry, index)
    top_left = corners[:-1, :-1]
    pure = (top_left >= 0) & (top_left == corners[1:, :-1]) & (top_left == corners[:-1, 1:]) & (top_left == corners[1:, 1:])
    rows, cols = np.nonzero(pure)
    facets = top_left[rows, cols]
    normal_cam = normals[facets] @ geometry.body_to_camera[index, :3, :3].T
    view_cam = -cameras.pixel_rays_cam(geometry.intrinsics, cols + 0.5, rows + 0.5)
    return rows, cols, facets, normal_cam, view_cam


def minnaert(albedo, minnaert_k, cos_i, cos_o):
    return albedo * cos_i**minnaert_k * cos_o ** (minnaert_k - 1)


def test_pure_pixels_hold_their_own_facets_values(variant, faceted_body, maps, tmp_path):
    vertices, faces, _, _, geometry = faceted_body
    albedo, minnaert_k = maps
    light = cameras.light_dir_cam(15.0)
    metadata = render.render_image_set(
        vertices, faces, geometry, albedo, minnaert_k, light, spp=8, out_dir=tmp_path, facet_maps_path=tmp_path / "facet_maps.npz"
    )
    n_checked, facets_checked, wrong_matches = 0, set(), 0
    for index in range(geometry.n_images):
        image = render.read_image(tmp_path / f"image_{index:03d}.exr")
        rows, cols, facets, normal_cam, view_cam = pure_pixel_facets(faceted_body, index)
        cos_i, cos_o = normal_cam @ light, (normal_cam * view_cam).sum(axis=1)
        lit = (cos_i > 0.05) & (cos_o > 0.05)
        rows, cols, facets, cos_i, cos_o = rows[lit], cols[lit], facets[lit], cos_i[lit], cos_o[lit]
        rendered = image[rows, cols]
        own = minnaert(albedo[facets], minnaert_k[facets], cos_i, cos_o)
        # perspective varies cos_o across a pixel by ~1e-3
        assert np.allclose(rendered, own, rtol=1e-3), np.abs(rendered / own - 1).max()
        # The check can fail: another facet's albedo and k (the next facet, same geometry) do not match.
        other = (facets + 1) % len(faces)
        wrong = minnaert(albedo[other], minnaert_k[other], cos_i, cos_o)
        wrong_matches += int(np.isclose(rendered, wrong, rtol=1e-3).sum())
        n_checked += len(facets)
        facets_checked.update(facets.tolist())
    assert n_checked > 1000 and len(facets_checked) > 20
    assert wrong_matches < 0.01 * n_checked
    # The scalar means alone do not describe the image either.
    assert not np.allclose(albedo, ALBEDO, rtol=0.05)

    # frames.json says the maps are per facet; the truth file holds them.
    frames = json.loads((tmp_path / "frames.json").read_text())
    assert frames == json.loads(json.dumps(metadata))
    assert frames["albedo"] == "per_facet" and frames["minnaert_k"] == "per_facet"
    assert frames["albedo_mean"] == pytest.approx(albedo.mean()) and frames["minnaert_k_mean"] == pytest.approx(minnaert_k.mean())
    assert frames["facet_maps"] == "facet_maps.npz"
    truth_albedo, truth_k = surface_maps.load_facet_maps(tmp_path / frames["facet_maps"])
    assert np.array_equal(truth_albedo, albedo) and np.array_equal(truth_k, minnaert_k)


def test_constant_maps_render_as_the_scalars(variant, faceted_body, tmp_path):
    """The per-facet path with every facet equal gives the scalar path's image, sample for sample."""
    vertices, faces, _, _, geometry = faceted_body
    light = cameras.light_dir_cam(10.0)
    scalar = render.render_image_set(vertices, faces, geometry, ALBEDO, MINNAERT_K, light, spp=4, out_dir=tmp_path / "scalar", seed=3)
    # One array, one scalar: the scalar is repeated over the facets.
    mixed = render.render_image_set(
        vertices, faces, geometry, np.full(len(faces), ALBEDO), MINNAERT_K, light, spp=4, out_dir=tmp_path / "mixed", seed=3
    )
    assert scalar["albedo"] == ALBEDO and scalar["minnaert_k"] == MINNAERT_K and "facet_maps" not in scalar
    assert mixed["albedo"] == "per_facet" and mixed["albedo_std"] < 1e-12 and mixed["minnaert_k"] == MINNAERT_K
    for index in range(geometry.n_images):
        name = f"image_{index:03d}.exr"
        reference = render.read_image(tmp_path / "scalar" / name)
        assert (reference > 0).sum() > 1000
        assert np.allclose(render.read_image(tmp_path / "mixed" / name), reference, rtol=1e-6, atol=0)


@pytest.mark.parametrize(
    "albedo, minnaert_k, message",
    [
        (np.full(7, 0.5), 0.8, "albedo.*one value per facet"),
        (0.5, np.full((2, 3), 0.8), "minnaert_k.*one value per facet"),
        ("per_facet_nan", 0.8, "albedo must be finite"),
        (0.5, "per_facet_zero", "minnaert_k must be finite and positive"),
    ],
)
def test_bad_per_facet_values_are_refused(faceted_body, tmp_path, albedo, minnaert_k, message):
    vertices, faces, _, _, geometry = faceted_body
    n_faces = len(faces)
    if isinstance(albedo, str):
        albedo = np.full(n_faces, 0.5)
        albedo[3] = np.nan
    if isinstance(minnaert_k, str):
        minnaert_k = np.full(n_faces, 0.8)
        minnaert_k[0] = 0.0
    with pytest.raises(ValueError, match=message):
        render.render_image_set(vertices, faces, geometry, albedo, minnaert_k, cameras.light_dir_cam(0.0), 1, tmp_path)
