"""Table 2's conditions of their own imaging geometry and relief: the views' ring, the Sun out of the camera's
x-z plane, the relief render and its truth on the shape model's facets, the rendered sets they start from."""

import json

import numpy as np
import pytest

from asteroid_photometry.core.config import condition_sets, renders_own_sets, ConfigError
from asteroid_photometry.core.footprint import estimate_footprint
from asteroid_photometry.evaluation.truth import rendered_truth, true_light, true_poses, truth_for_facets
from asteroid_photometry.experiments.table1 import render_set, write_imaging_geometry
from asteroid_photometry.from_images import refine
from asteroid_photometry.world import cameras, relief, render, shape, surface_maps
from asteroid_photometry.world.image_sets import ImageSet, condition_rendered_set, image_sets

FIELD = {"name": "field", "kind": "random_field", "albedo_contrast": 0.2, "k_contrast": 0.1, "correlation_length_m": 80, "seed": 1}
RELIEF = {"subdivisions": 1, "rms_slope_deg": 3.0, "seed": 0}


@pytest.fixture(scope="module")
def shape_npz(tmp_path_factory):
    """The coarse radar model of Itokawa, prepared as rule prepare_shape does."""
    spec = shape.SHAPE_MODELS["ostro_radar"]
    return shape.write_prepared_model(spec.shipped_path, "ostro_radar", tmp_path_factory.mktemp("shape") / "model.npz")


def latitudes_deg(centres):
    return np.degrees(np.arcsin(centres[:, 2] / np.linalg.norm(centres, axis=1)))


# --- the Sun out of the camera's x-z plane ------------------------------------------------


@pytest.mark.parametrize("light_angle", [0.0, 10.0, 40.0])
@pytest.mark.parametrize("tilt", [-20.0, 20.0, 35.0])
def test_the_tilted_sun_lies_out_of_the_x_z_plane_by_the_asked_angle_over_the_sets_light_angle(light_angle, tilt):
    light = cameras.tilted_light_dir_cam(light_angle, tilt)
    assert np.linalg.norm(light) == pytest.approx(1.0, abs=1e-15)
    assert np.degrees(np.arcsin(light[1])) == pytest.approx(tilt, abs=1e-12)  # out of the x-z plane, towards +y when positive
    assert np.degrees(np.arctan2(light[0], -light[2])) == pytest.approx(light_angle, abs=1e-12)  # in the plane: the set's angle
    phase = np.degrees(np.arccos(np.cos(np.radians(light_angle)) * np.cos(np.radians(tilt))))
    assert np.degrees(np.arccos(-light[2])) == pytest.approx(phase, abs=1e-9)


@pytest.mark.parametrize("light_angle", [0.0, 10.0, 37.5])
def test_no_tilt_is_the_sets_own_light_bit_for_bit(light_angle):
    assert np.array_equal(cameras.tilted_light_dir_cam(light_angle, 0.0), cameras.light_dir_cam(light_angle))
    assert not np.allclose(cameras.tilted_light_dir_cam(light_angle, 1.0), cameras.light_dir_cam(light_angle))


# --- the views' ring, and the refinement's spin axis -------------------------------------


@pytest.mark.parametrize("latitude", [0.0, 20.0, -35.0])
def test_a_conditions_cameras_ring_the_spin_axis_at_its_latitude_and_the_refinement_finds_that_axis(shape_npz, tmp_path, latitude):
    out = tmp_path / f"cameras_lat{latitude:g}.json"
    write_imaging_geometry(shape_npz, out, n_images=36, image_size=64, camera_distance_km=5.0, view_latitude_deg=latitude)
    geometry = cameras.load_imaging_geometry(out)
    centres = cameras.camera_centres_body(geometry.body_to_camera)
    assert np.allclose(latitudes_deg(centres), latitude, atol=1e-9)
    assert np.allclose(np.linalg.norm(centres[:, :2], axis=1), 5000.0 * np.cos(np.radians(latitude)), rtol=1e-12)  # a ring about z
    # A ring of one latitude lies in a plane normal to the spin axis: the refinement's axis (from the cameras alone).
    axis = refine.spin_axis(centres)
    assert abs(abs(axis[2]) - 1.0) < 1e-12
    # ... and the scoring's spin axis in the camera frame (the true pose of image 0) is that axis, seen from image 0.
    rotation = geometry.body_to_camera[0, :3, :3]
    assert abs(abs(float((rotation @ axis) @ (rotation @ [0.0, 0.0, 1.0]))) - 1.0) < 1e-12
    # The projected spin axis points up in the image (-y), whatever the latitude.
    spin_cam = rotation @ [0.0, 0.0, 1.0]
    assert spin_cam[1] < 0 and abs(spin_cam[0]) < 1e-12
    assert np.degrees(np.arcsin(-spin_cam[2])) == pytest.approx(latitude, abs=1e-9)


def test_views_at_latitude_20_and_the_sun_20_out_of_plane_put_the_sun_near_the_bodys_equator():
    """What config/conditions_geometry.yaml's oblique condition means on the body (docs/table2.md, section 0)."""
    rotation = cameras.inertial_to_camera_rotation(20.0)
    spin_cam = rotation @ [0.0, 0.0, 1.0]
    for light_angle in (0.0, 10.0, 30.0):
        # The Sun's component along the axis: sin 20 cos 20 (cos a - 1), zero at light angle 0 and small after.
        light = cameras.tilted_light_dir_cam(light_angle, 20.0)
        expected = np.sin(np.radians(20.0)) * np.cos(np.radians(20.0)) * (np.cos(np.radians(light_angle)) - 1.0)
        assert light @ spin_cam == pytest.approx(expected, abs=1e-12)
    # The other sign puts the Sun at latitude 40.
    assert np.degrees(np.arcsin(cameras.tilted_light_dir_cam(0.0, -20.0) @ spin_cam)) == pytest.approx(40.0, abs=1e-9)


# --- the rendered sets a condition starts from --------------------------------------------


def test_a_condition_of_its_own_views_sun_or_relief_starts_from_its_own_render():
    amica = {"name": "amica", "surface_map": "field", "view_latitude_deg": 0.0, "light_out_of_plane_deg": 0.0, "relief": None}
    oblique = {**amica, "name": "oblique", "view_latitude_deg": 20.0, "light_out_of_plane_deg": 20.0}
    bumpy = {**amica, "name": "bumpy", "surface_map": None, "relief": RELIEF}
    sun = {**amica, "name": "sun", "light_out_of_plane_deg": -5.0}
    assert [renders_own_sets(entry) for entry in (amica, oblique, bumpy, sun)] == [False, True, True, True]
    set_id = "light10_albedo0.6_k0.8"
    assert condition_rendered_set(set_id, amica) == "light10_albedo0.6_k0.8_map-field"
    assert condition_rendered_set(set_id, oblique) == "light10_albedo0.6_k0.8_map-field_imaging-oblique"
    assert condition_rendered_set(set_id, bumpy) == "light10_albedo0.6_k0.8_imaging-bumpy"


def test_the_footprint_counts_a_conditions_own_renders():
    config = {"n_images": 36, "image_size": 512, "albedos": [0.6], "minnaert_k": [0.8], "light_angles_deg": [0, 10], "noise_levels": [], "surface_maps": []}
    sets = image_sets(config)
    ideal = {"ideal": {"name": "ideal"}}
    plain = estimate_footprint(config, sets, 1, 1, conditions=ideal)
    oblique = estimate_footprint(config, sets, 1, 1, conditions={**ideal, "oblique": {"name": "oblique", "view_latitude_deg": 20.0}})
    assert oblique.n_sets == plain.n_sets + 2
    assert oblique.disk_bytes["rendered images"] == pytest.approx(2 * plain.disk_bytes["rendered images"])
    # On one of the two base sets (its key sets): one render of its own, one mission set more.
    one = estimate_footprint(config, sets, 1, 1, conditions={**ideal, "oblique": {"name": "oblique", "view_latitude_deg": 20.0}},
                             condition_sets={"ideal": ["light0_albedo0.6_k0.8", "light10_albedo0.6_k0.8"], "oblique": ["light10_albedo0.6_k0.8"]})
    assert one.n_sets == plain.n_sets + 1
    assert one.disk_bytes["mission sets"] == pytest.approx(1.5 * plain.disk_bytes["mission sets"])


def test_a_condition_runs_on_the_base_sets_it_names_in_their_order_and_refuses_others():
    base = ["light0_albedo0.5_k0.8", "light0_albedo0.7_k0.8", "light10_albedo0.5_k0.8"]
    conditions = {"ideal": {"name": "ideal", "sets": None}, "oblique": {"name": "oblique", "sets": ["light10_albedo0.5_k0.8", "light0_albedo0.5_k0.8"]}}
    assert condition_sets(conditions, base) == {"ideal": base, "oblique": ["light0_albedo0.5_k0.8", "light10_albedo0.5_k0.8"]}
    with pytest.raises(ConfigError, match=r"config key 'imaging_conditions' \(oblique\): sets \['light10_albedo0.6_k0.8'\] are not base sets"):
        condition_sets({"oblique": {"name": "oblique", "sets": ["light10_albedo0.6_k0.8"]}}, base)


# --- the renders ------------------------------------------------------------------------------


def test_the_oblique_render_records_its_ring_and_tilted_sun_as_the_truth(shape_npz, tmp_path):
    cameras_json = tmp_path / "cameras_lat20.json"
    write_imaging_geometry(shape_npz, cameras_json, n_images=3, image_size=64, camera_distance_km=2.0, view_latitude_deg=20.0)
    image_set = ImageSet(10.0, 0.6, 0.8)
    render_set(shape_npz, cameras_json, image_set, 1, "auto", tmp_path / "oblique", light_out_of_plane_deg=20.0)
    frames = rendered_truth(tmp_path / "oblique")
    assert np.array_equal(true_light(frames), cameras.tilted_light_dir_cam(10.0, 20.0))
    assert np.degrees(np.arcsin(true_light(frames)[1])) == pytest.approx(20.0)
    assert np.allclose(latitudes_deg(cameras.camera_centres_body(true_poses(frames))), 20.0, atol=1e-9)
    assert frames["condition_render"] == {"view_latitude_deg": 20.0, "light_out_of_plane_deg": 20.0, "relief": None}
    assert render.read_image(tmp_path / "oblique" / "image_000.exr").max() > 0


def test_the_relief_render_keeps_its_truth_on_the_shape_models_facets(shape_npz, tmp_path):
    cameras_json = tmp_path / "cameras.json"
    write_imaging_geometry(shape_npz, cameras_json, n_images=1, image_size=96, camera_distance_km=2.0, view_latitude_deg=0.0)
    image_set = ImageSet(10.0, 0.6, 0.8, surface_map="field")
    render_set(shape_npz, cameras_json, image_set, 1, "auto", tmp_path / "relief", surface_map=FIELD, relief_spec=RELIEF)
    render_set(shape_npz, cameras_json, image_set, 1, "auto", tmp_path / "flat", surface_map=FIELD)
    model = shape.load_shape_npz(shape_npz)
    n_facets = len(model["faces"])

    frames = rendered_truth(tmp_path / "relief")
    assert frames["render_mesh"] == {"vertices": frames["render_mesh"]["vertices"], "faces": 4 * n_facets, "shape_model_facets": n_facets}
    record = frames["condition_render"]["relief"]
    assert record["faces"] == 4 * n_facets and record["achieved_rms_slope_deg"] == pytest.approx(3.0, rel=1e-3)
    # The truth per shape-model facet: the same maps as the flat render's, the shape model's normals.
    albedo_map, k_map = surface_maps.facet_maps(model["centroids_m"], {key: FIELD[key] for key in surface_maps.SPEC_KEYS["random_field"]}, 1, 0.6, 0.8)
    facets = np.array([0, 7, n_facets - 1])
    albedo, minnaert_k, normals, light = truth_for_facets(facets, model, frames, tmp_path / "relief")
    assert np.array_equal(albedo, albedo_map[facets]) and np.array_equal(minnaert_k, k_map[facets])
    assert np.array_equal(normals, model["normals"][facets])
    assert np.array_equal(light, cameras.light_dir_cam(10.0))
    flat_truth = truth_for_facets(facets, model, rendered_truth(tmp_path / "flat"), tmp_path / "flat")
    assert all(np.array_equal(a, b) for a, b in zip(flat_truth, (albedo, minnaert_k, normals, light)))
    # The images are the relief's: the same body and light, other pixels.
    with_relief, flat = (render.read_image(tmp_path / name / "image_000.exr") for name in ("relief", "flat"))
    lit = (with_relief > 0) & (flat > 0)
    assert lit.sum() > 500 and not np.allclose(with_relief[lit], flat[lit], rtol=1e-3)
    # The fine mesh the render used is the relief of the shape model that the spec asks for.
    vertices, faces, parent = relief.relief_mesh(model["vertices_m"], model["faces"], levels=1, rms_slope_deg=3.0, seed=0)
    assert len(faces) == frames["render_mesh"]["faces"] and len(vertices) == frames["render_mesh"]["vertices"]
    assert np.array_equal(parent, np.repeat(np.arange(n_facets), 4))
    assert json.loads((tmp_path / "relief" / "frames.json").read_text())["facet_maps"] == surface_maps.FACET_MAPS_FILE
