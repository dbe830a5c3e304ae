"""Relief below the shape model's resolution: the subdivision's parent map, the slope asked for, the rendered mesh."""

import json

import numpy as np
import pytest

from asteroid_photometry.world import cameras, observe, relief, render, shape, surface_maps

# An off-axis tetrahedron, outward-wound (as in test_render).
TETRAHEDRON = (
    np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [0.0, 60.0, 0.0], [0.0, 0.0, 60.0]]) + [40.0, 25.0, -30.0],
    np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
)


@pytest.fixture(scope="module")
def itokawa():
    model = shape.load_shape_model(shape.SHAPE_MODELS["gaskell_ver64q"].shipped_path, "gaskell_ver64q").compacted()
    return model.vertices_m, model.faces


@pytest.fixture(scope="module")
def itokawa_radar():
    model = shape.load_shape_model(shape.SHAPE_MODELS["ostro_radar"].shipped_path, "ostro_radar").compacted()
    return model.vertices_m, model.faces


def slopes_deg(vertices, faces, parent, vertices_in, faces_in):
    """Each fine face's angle to its parent facet, and its area: computed here, from the meshes alone."""
    _, normals, areas = shape.facet_geometry(vertices, faces)
    _, parent_normals, _ = shape.facet_geometry(vertices_in, faces_in)
    cos = np.clip(np.einsum("ij,ij->i", normals, parent_normals[parent]), -1.0, 1.0)
    return np.degrees(np.arccos(cos)), areas


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_children_tile_their_parent(levels):
    vertices_in, faces_in = TETRAHEDRON
    vertices, faces, parent = relief.subdivide(vertices_in, faces_in, levels)
    assert len(faces) == 4**levels * len(faces_in)
    assert np.array_equal(parent, np.repeat(np.arange(len(faces_in)), 4**levels))
    assert np.array_equal(vertices[: len(vertices_in)], vertices_in)
    # Closed: each edge is shared by two faces; V - E + F = 2 for the subdivided tetrahedron.
    assert shape.mesh_closure_problem(faces, len(vertices)) is None
    assert len(vertices) - 3 * len(faces) // 2 + len(faces) == 2
    centroids, normals, areas = shape.facet_geometry(vertices, faces)
    _, parent_normals, parent_areas = shape.facet_geometry(vertices_in, faces_in)
    assert np.allclose(np.bincount(parent, weights=areas), parent_areas, rtol=1e-12)
    assert np.allclose(normals, parent_normals[parent], atol=1e-12)  # wound as the parent
    # Every child's centroid lies inside its parent: barycentric coordinates all positive.
    a, b, c = (vertices_in[faces_in[parent, corner]] for corner in range(3))
    matrix = np.stack([b - a, c - a, parent_normals[parent]], axis=2)
    beta_gamma_height = np.linalg.solve(matrix, (centroids - a)[..., None])[..., 0]
    beta, gamma, height = beta_gamma_height.T
    assert np.all(np.abs(height) < 1e-9)
    assert np.all(beta > 0) and np.all(gamma > 0) and np.all(beta + gamma < 1)
    # The parent map is wrong if it is shuffled: a moved child leaves its parent.
    wrong = np.roll(parent, 1)
    a, b, c = (vertices_in[faces_in[wrong, corner]] for corner in range(3))
    coords = np.linalg.solve(np.stack([b - a, c - a, parent_normals[wrong]], axis=2), (centroids - a)[..., None])[..., 0]
    assert not np.all((coords[:, 0] > 0) & (coords[:, 1] > 0) & (coords[:, :2].sum(axis=1) < 1))


def test_relief_keeps_the_parent_map_and_moves_new_vertices_along_the_surface_normal(itokawa_radar):
    vertices_in, faces_in = itokawa_radar
    vertices, faces, parent = relief.relief_mesh(vertices_in, faces_in, levels=2, rms_slope_deg=3.0, seed=4)
    flat, flat_faces, flat_parent = relief.subdivide(vertices_in, faces_in, 2)
    assert np.array_equal(faces, flat_faces) and np.array_equal(parent, flat_parent)
    assert np.array_equal(vertices[: len(vertices_in)], vertices_in)
    moved = vertices - flat
    new = np.arange(len(vertices_in), len(vertices))
    assert np.all(np.linalg.norm(moved[new], axis=1) > 0)
    assert 0.005 < np.sqrt(np.mean(np.sum(moved[new] ** 2, axis=1))) < 0.5  # centimetres
    # The shape-model facets each new vertex lies on: one inside a facet, two on an edge.
    pairs = np.unique(np.column_stack([faces.ravel(), np.repeat(parent, 3)]), axis=0)
    pairs = pairs[pairs[:, 0] >= len(vertices_in)]
    vertex, count = np.unique(pairs[:, 0], return_counts=True)
    assert np.array_equal(vertex, new) and set(np.unique(count)) == {1, 2}
    _, normals, _ = shape.facet_geometry(vertices_in, faces_in)
    start = np.searchsorted(pairs[:, 0], vertex)
    d = moved[vertex] / np.linalg.norm(moved[vertex], axis=1, keepdims=True)
    inside = count == 1
    n1 = normals[pairs[start, 1]]
    assert np.all(np.linalg.norm(np.cross(d[inside], n1[inside]), axis=1) < 1e-6)  # along the facet's normal
    # On an edge: in the plane of the two facets' normals, on the same side of both facets.
    n2 = normals[pairs[np.minimum(start + 1, len(pairs) - 1), 1]]
    crease = np.cross(n1[~inside], n2[~inside])
    assert np.all(np.abs(np.einsum("ij,ij->i", d[~inside], crease)) < 1e-6)
    assert np.all(np.sign(np.einsum("ij,ij->i", d[~inside], n1[~inside])) == np.sign(np.einsum("ij,ij->i", d[~inside], n2[~inside])))


@pytest.mark.parametrize("model, levels, rms_slope", [("itokawa", 1, 3.0), ("itokawa_radar", 2, 1.5), ("itokawa_radar", 1, 6.0)])
def test_rms_slope_is_the_one_asked_for(request, model, levels, rms_slope):
    vertices_in, faces_in = request.getfixturevalue(model)
    vertices, faces, parent = relief.relief_mesh(vertices_in, faces_in, levels=levels, rms_slope_deg=rms_slope, seed=1)
    slopes, areas = slopes_deg(vertices, faces, parent, vertices_in, faces_in)
    achieved = np.sqrt(np.sum(areas * slopes**2) / areas.sum())
    assert achieved == pytest.approx(rms_slope, rel=0.2)
    # Relief everywhere, not a few spikes: most faces tilt by a sizeable part of the RMS.
    assert np.median(slopes) > 0.4 * rms_slope
    assert np.mean(slopes > 3.0 * rms_slope) < 0.01
    assert slopes.max() < 12.0 * rms_slope  # nothing folds over, slender facets included
    # Still a closed, outward body of the same volume.
    assert shape.mesh_closure_problem(faces, len(vertices)) is None
    assert shape.signed_volume(vertices, faces) == pytest.approx(shape.signed_volume(vertices_in, faces_in), rel=1e-4)


def test_seed_reproduces_the_relief_and_another_seed_changes_it():
    vertices_in, faces_in = relief.subdivide(*TETRAHEDRON, 2)[:2]  # a mesh with more facets than four
    first = relief.relief_mesh(vertices_in, faces_in, levels=2, rms_slope_deg=3.0, seed=7)
    again = relief.relief_mesh(vertices_in, faces_in, levels=2, rms_slope_deg=3.0, seed=7)
    other = relief.relief_mesh(vertices_in, faces_in, levels=2, rms_slope_deg=3.0, seed=8)
    for mine, theirs in zip(first, again):
        assert np.array_equal(mine, theirs)
    assert np.array_equal(first[1], other[1]) and np.array_equal(first[2], other[2])
    assert np.abs(first[0] - other[0]).max() > 1e-3


@pytest.mark.parametrize("levels, rms_slope", [(0, 3.0), (2, 0.0), (0, 0.0)])
def test_no_level_or_no_slope_returns_the_input(levels, rms_slope):
    vertices_in, faces_in = TETRAHEDRON
    vertices, faces, parent = relief.relief_mesh(vertices_in, faces_in, levels=levels, rms_slope_deg=rms_slope, seed=3)
    assert np.array_equal(vertices, vertices_in) and vertices.dtype == np.float64
    assert np.array_equal(faces, faces_in) and faces.dtype == np.int64
    assert np.array_equal(parent, np.arange(len(faces_in)))


@pytest.mark.parametrize("arguments", [dict(levels=-1), dict(levels=1.5), dict(rms_slope_deg=-1.0), dict(rms_slope_deg=float("nan")), dict(correlation_length_m=0.0)])
def test_bad_arguments_are_refused(arguments):
    with pytest.raises(ValueError, match="relief"):
        relief.relief_mesh(*TETRAHEDRON, **{"levels": 1, "rms_slope_deg": 3.0, **arguments})


def test_rendered_relief_takes_its_parents_albedo_and_varies_across_a_flat_facet(tmp_path):
    """Per-facet albedo through parent_facet renders as the expanded albedo; a facet's pure pixels now differ."""
    vertices_in, faces_in = TETRAHEDRON
    geometry = cameras.make_imaging_geometry(n_images=1, image_size=128, camera_distance_km=2.0, view_latitude_deg=20.0, body_radius_m=130.0)
    light = cameras.light_dir_cam(30.0, 160.0)  # the facet in view is lit at about 70 deg incidence
    albedo, minnaert_k = np.array([0.5, 0.6, 0.7, 0.8]), 0.75
    vertices, faces, parent = relief.relief_mesh(vertices_in, faces_in, levels=3, rms_slope_deg=3.0, seed=2)

    metadata = render.render_image_set(vertices, faces, geometry, albedo, minnaert_k, light, 4, tmp_path / "hook", facet_maps_path=tmp_path / "hook" / "maps.npz", parent_facet=parent)
    render.render_image_set(vertices, faces, geometry, albedo[parent], minnaert_k, light, 4, tmp_path / "expanded")
    render.render_image_set(vertices_in, faces_in, geometry, albedo, minnaert_k, light, 4, tmp_path / "flat")
    hook, expanded, flat = (render.read_image(tmp_path / name / "image_000.exr") for name in ("hook", "expanded", "flat"))
    assert np.array_equal(hook, expanded) and hook.max() > 0
    maps_albedo, maps_k = surface_maps.load_facet_maps(tmp_path / "hook" / "maps.npz")
    assert np.array_equal(maps_albedo, albedo) and np.array_equal(maps_k, np.full(4, minnaert_k))
    written = json.loads((tmp_path / "hook" / "frames.json").read_text())
    assert written["render_mesh"] == {"vertices": len(vertices), "faces": len(faces), "shape_model_facets": 4} == metadata["render_mesh"]
    assert written["albedo_mean"] == pytest.approx(albedo.mean())

    # Pixels wholly on one shape-model facet (its children, with relief): the flat facet's
    # are equal but for perspective, the relief's spread by the children's tilts.
    raycaster = observe.BodyRaycaster(vertices, faces)
    corners = observe.corner_facet_ids(raycaster, geometry, 0)
    corners = np.where(corners >= 0, parent[np.maximum(corners, 0)], -1)
    top_left = corners[:-1, :-1]
    pure = (top_left >= 0) & (top_left == corners[1:, :-1]) & (top_left == corners[:-1, 1:]) & (top_left == corners[1:, 1:])
    spreads = []
    for facet in np.unique(top_left[pure]):
        on_facet = pure & (top_left == facet) & (flat > 0) & (hook > 0)
        if on_facet.sum() >= 100:
            spreads.append((np.std(hook[on_facet]) / np.mean(hook[on_facet]), np.std(flat[on_facet]) / np.mean(flat[on_facet])))
    assert len(spreads) >= 1
    for with_relief, without in spreads:
        assert without < 0.01 and with_relief > 0.01 and with_relief > 3 * without
