"""Tests of asteroid_photometry.world.shape: parsing, verification, facet geometry, download, prepared model."""

import gzip
import hashlib
import logging
import lzma
import runpy
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from asteroid_photometry.world import shape
from asteroid_photometry.world.shape import ShapeModelError
from synthetic_helpers import BOX_CORNERS, BOX_FACES

SCRIPTS_DIR = Path(__file__).parents[1] / "workflow" / "scripts"

# Figures from workflow/resources/shape/SOURCES.md.
SHARED_MODELS = {
    "gaskell_ver64q": dict(
        file_name="itokawa_low.obj",
        extent_m=(561.7, 305.1, 243.4),
        volume_km3=0.017786,
        area_km2=0.39855,
        n_vertices=25350,
        n_vertices_used=24578,
        n_facets=49152,
    ),
    "ostro_radar": dict(
        file_name="25143itokawa.tab",
        extent_m=(548.1, 312.6, 275.5),
        volume_km3=0.024060,
        area_km2=0.4374,
        n_vertices=6098,
        n_vertices_used=6098,
        n_facets=12192,
    ),
}

# A cube of side 100 m centred on the origin, facets counter-clockwise seen from outside.
CUBE_VERTICES_KM = 0.05 * BOX_CORNERS
CUBE_FACES = BOX_FACES


def write_obj(path, vertices_km, faces, line_end="\n"):
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices_km]
    lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in faces]
    Path(path).write_text(line_end.join(lines) + line_end, newline="")
    return Path(path)


def write_gaskell(path, vertices_km, faces, counts_in_header=True):
    """Write a Gaskell plate model: header 'NV NF' (or 'NV', with NF after the vertices)."""
    lines = [f"{len(vertices_km):10d} {len(faces):10d}" if counts_in_header else f"{len(vertices_km):10d}"]
    lines += [f"{n:10d} {x:12.6f} {y:12.6f} {z:12.6f}" for n, (x, y, z) in enumerate(vertices_km, start=1)]
    if not counts_in_header:
        lines.append(f"{len(faces):10d}")
    lines += [f"{n:10d} {i + 1:10d} {j + 1:10d} {k + 1:10d}" for n, (i, j, k) in enumerate(faces, start=1)]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def register_model(monkeypatch, name, vertices_km, faces, urls=("file:///nonexistent/model.tab",)):
    """Add a registry entry for a small test mesh, with counts and checksum taken from it."""
    n_used = len(np.unique(faces))
    spec = shape.ShapeModelSpec(
        name=name,
        description="test mesh",
        citation="none",
        file_name=f"{name}.tab",
        urls=tuple(urls),
        n_vertices=len(vertices_km),
        n_vertices_used=n_used,
        n_facets=len(faces),
        geometry_sha256=shape.geometry_sha256(vertices_km, faces),
        shipped_file=f"{name}.obj.xz",
    )
    monkeypatch.setitem(shape.SHAPE_MODELS, name, spec)
    return spec


@pytest.fixture(scope="module")
def shared_models(itokawa_dir):
    """Each shared model loaded once: name -> ShapeModel."""
    return {
        name: shape.load_shape_model(itokawa_dir / facts["file_name"], name)
        for name, facts in SHARED_MODELS.items()
    }


@pytest.fixture
def cube_model(monkeypatch, tmp_path):
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES)
    return write_obj(tmp_path / "cube.obj", CUBE_VERTICES_KM, CUBE_FACES)


# ---------------------------------------------------------------- registry and shipped files

# sha256 of each model file as its archive serves it, before compression (SOURCES.md).
ARCHIVE_SHA256 = {
    "gaskell_ver64q": "1879abcde28ca60f8616da212d6f7ae51dbc0cfc47ef271228d1bd2719b2a26b",
    "ostro_radar": "2d3744cc13c0007db70eb28734ec9b40678e155fb1cb5f7949ee375fef6b5557",
}


@pytest.mark.parametrize("name", sorted(SHARED_MODELS))
def test_shipped_copy_is_the_archive_file_and_loads_compressed(name):
    spec = shape.SHAPE_MODELS[name]
    assert spec.shipped_path.is_file() and spec.shipped_path.stat().st_size < 300_000
    assert hashlib.sha256(lzma.decompress(spec.shipped_path.read_bytes())).hexdigest() == ARCHIVE_SHA256[name]
    sources = (spec.shipped_path.parent / "SOURCES.md").read_text()
    assert spec.shipped_file in sources and ARCHIVE_SHA256[name] in sources
    assert hashlib.sha256(spec.shipped_path.read_bytes()).hexdigest() in sources
    model = shape.load_shape_model(spec.shipped_path, name)
    assert model.geometry_sha256 == spec.geometry_sha256 and len(model.faces) == spec.n_facets


def test_compressed_files_are_read_and_a_broken_one_is_named(cube_model, tmp_path):
    text = cube_model.read_bytes()
    expected = shape.read_shape_file(cube_model)
    for suffix, compress in ((".xz", lzma.compress), (".gz", gzip.compress)):
        packed = tmp_path / f"cube.obj{suffix}"
        packed.write_bytes(compress(text))
        vertices_km, faces = shape.read_shape_file(packed)
        assert np.array_equal(vertices_km, expected[0]) and np.array_equal(faces, expected[1])
    truncated = tmp_path / "cube_truncated.obj.xz"
    truncated.write_bytes(lzma.compress(text)[:40])
    with pytest.raises(ShapeModelError, match="cube_truncated.obj.xz: cannot decompress"):
        shape.read_shape_file(truncated)



def test_registry_describes_both_models():
    assert shape.DEFAULT_SHAPE_MODEL == "gaskell_ver64q"
    for name, facts in SHARED_MODELS.items():
        spec = shape.SHAPE_MODELS[name]
        assert spec.name == name
        assert (spec.n_vertices, spec.n_vertices_used, spec.n_facets) == (
            facts["n_vertices"], facts["n_vertices_used"], facts["n_facets"]
        )
        assert spec.description and spec.citation
        assert spec.urls and all(url.startswith("https://sbnarchive.psi.edu/") for url in spec.urls)
        assert spec.urls[0].endswith("/" + spec.file_name)
        assert len(spec.geometry_sha256) == 64


@pytest.mark.parametrize("name", sorted(SHARED_MODELS))
def test_shared_file_counts_and_checksum(shared_models, name):
    model = shared_models[name]
    facts = SHARED_MODELS[name]
    assert model.name == name
    assert model.vertices_m.shape == (facts["n_vertices"], 3) and model.vertices_m.dtype == np.float64
    assert model.faces.shape == (facts["n_facets"], 3) and model.faces.dtype == np.int64
    assert model.faces.min() == 0
    assert model.geometry_sha256 == shape.SHAPE_MODELS[name].geometry_sha256
    assert model.source_path.name == facts["file_name"]


@pytest.mark.parametrize("name", sorted(SHARED_MODELS))
def test_shared_file_extent_is_in_metres(shared_models, name):
    vertices_m = shared_models[name].compacted().vertices_m
    extent_m = vertices_m.max(axis=0) - vertices_m.min(axis=0)
    np.testing.assert_allclose(extent_m, SHARED_MODELS[name]["extent_m"], atol=1.0)


@pytest.mark.parametrize("name", sorted(SHARED_MODELS))
def test_shared_file_volume_and_area(shared_models, name):
    model = shared_models[name]
    facts = SHARED_MODELS[name]
    volume_m3 = shape.signed_volume(model.vertices_m, model.faces)
    _, _, areas_m2 = shape.facet_geometry(model.vertices_m, model.faces)
    assert volume_m3 == pytest.approx(facts["volume_km3"] * 1e9, rel=1e-4)
    assert areas_m2.sum() == pytest.approx(facts["area_km2"] * 1e6, rel=2e-4)


def test_gaskell_unused_vertices_are_compacted(shared_models):
    model = shared_models["gaskell_ver64q"]
    compact = model.compacted()
    assert len(compact.vertices_m) == 24578
    assert compact.faces.max() == 24577
    assert len(np.unique(compact.faces)) == 24578
    # Same triangles, same facet order.
    np.testing.assert_array_equal(compact.vertices_m[compact.faces], model.vertices_m[model.faces])
    assert compact.geometry_sha256 == model.geometry_sha256


def test_compact_mesh_keeps_vertex_order():
    unused_km = np.array([[9.0, 9.0, 9.0]])
    vertices_km = np.concatenate([CUBE_VERTICES_KM[:4], unused_km, CUBE_VERTICES_KM[4:], unused_km])
    faces = np.where(CUBE_FACES >= 4, CUBE_FACES + 1, CUBE_FACES)
    kept_km, kept_faces, kept_index = shape.compact_mesh(vertices_km, faces)
    np.testing.assert_array_equal(kept_index, [0, 1, 2, 3, 5, 6, 7, 8])
    np.testing.assert_array_equal(kept_km, CUBE_VERTICES_KM)
    np.testing.assert_array_equal(kept_faces, CUBE_FACES)
    assert shape.geometry_sha256(vertices_km, faces) == shape.geometry_sha256(CUBE_VERTICES_KM, CUBE_FACES)


# ---------------------------------------------------------------- format independence


def test_checksum_same_in_gaskell_plate_format(shared_models, tmp_path):
    obj_model = shared_models["gaskell_ver64q"]
    plate_path = write_gaskell(tmp_path / "ver64q.tab", obj_model.vertices_m / 1000.0, obj_model.faces)
    plate_model = shape.load_shape_model(plate_path, "gaskell_ver64q")
    assert plate_model.geometry_sha256 == obj_model.geometry_sha256
    np.testing.assert_array_equal(plate_model.faces, obj_model.faces)
    np.testing.assert_allclose(plate_model.vertices_m, obj_model.vertices_m, atol=1e-9)


def test_compacted_re_export_is_the_same_model(shared_models, tmp_path):
    # Re-exports (PLY/STL converted back to OBJ) carry only the 24578 used vertices.
    compact = shared_models["gaskell_ver64q"].compacted()
    obj_path = write_obj(tmp_path / "itokawa_24578.obj", compact.vertices_m / 1000.0, compact.faces)
    assert shape.load_shape_model(obj_path, "gaskell_ver64q").geometry_sha256 == compact.geometry_sha256


def test_checksum_ignores_number_notation():
    text_fixed = "v 0.082 -0.15153 0.1\nv 0 0 0\nv 0.1 0 0\nf 1 2 3\n"
    text_exp = "v 8.200000e-02 -1.515300e-01 1.000000e-01\r\nv 0.0 0.0 0.0\r\nv 1.0e-01 0 0\r\nf 1 2 3\r\n"
    assert shape.geometry_sha256(*shape.parse_shape_text(text_fixed)) == shape.geometry_sha256(
        *shape.parse_shape_text(text_exp)
    )


@pytest.mark.parametrize("counts_in_header", [True, False])
def test_gaskell_format_header_variants(tmp_path, counts_in_header):
    path = write_gaskell(tmp_path / "cube.tab", CUBE_VERTICES_KM, CUBE_FACES, counts_in_header)
    vertices_km, faces = shape.read_shape_file(path)
    np.testing.assert_array_equal(vertices_km, CUBE_VERTICES_KM)
    np.testing.assert_array_equal(faces, CUBE_FACES)


def test_obj_comments_crlf_and_slashed_indices():
    text = "# cube corner\r\no corner\r\nv 0 0 0\r\nv 1 0 0 # x\r\nv 0 1 0\r\nvn 0 0 1\r\nf 1//1 2//1 3//1\r\n"
    vertices_km, faces = shape.parse_shape_text(text)
    assert vertices_km.shape == (3, 3)
    np.testing.assert_array_equal(faces, [[0, 1, 2]])


# ---------------------------------------------------------------- errors


def test_unknown_model_name_names_the_config_key(tmp_path):
    with pytest.raises(ShapeModelError, match=r"unknown shape model 'eros'.*'shape_model'.*gaskell_ver64q"):
        shape.load_shape_model(tmp_path / "any.obj", "eros")


def test_missing_file_names_file_and_config_key(tmp_path):
    missing = tmp_path / "nowhere" / "ver64q.tab"
    with pytest.raises(ShapeModelError) as caught:
        shape.load_shape_model(missing, "gaskell_ver64q")
    assert str(missing) in str(caught.value)
    assert "not found" in str(caught.value) and "shape_model_path" in str(caught.value)


@pytest.mark.parametrize(
    "text, line_number, problem",
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 x\nf 1 2 3\n", 4, "not numbers"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", 4, "only triangular"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3.5\n", 4, "not integers"),
        ("v 0 0 0\nv 1 0 0\n\nv 0 1 0\nbanana 3\nf 1 2 3\n", 5, "unexpected OBJ statement"),
        ("hello world\n", 1, "neither an OBJ-like model"),
        ("3 1\n1 0 0 0\n2 1 0 0\n4 0 1 0\n1 1 2 3\n", 4, "out of sequence"),
        ("3 1\n1 0 0 0\n2 1 0 0\n3 0 1 0\n1 1 2 3\n2 1 3 2\n", 6, "unexpected content after"),
    ],
)
def test_garbled_content_names_file_and_line(tmp_path, text, line_number, problem):
    path = tmp_path / "garbled.tab"
    path.write_text(text)
    with pytest.raises(ShapeModelError) as caught:
        shape.read_shape_file(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: line {line_number}: ")
    assert problem in message


def test_truncated_gaskell_file(tmp_path):
    path = tmp_path / "truncated.tab"
    path.write_text("3 1\n1 0 0 0\n2 1 0 0\n")
    with pytest.raises(ShapeModelError, match=r"truncated\.tab: the file ends after vertex 2 of 3"):
        shape.read_shape_file(path)


@pytest.mark.parametrize("content", [b"", b"\n  \r\n", b"\x1f\x8b\x08\x00", b"v 0 0 0\nv 1 0 0\nv \xff 1 0\n"])
def test_empty_binary_or_compressed_file(tmp_path, content):
    path = tmp_path / "odd.tab"
    path.write_bytes(content)
    with pytest.raises(ShapeModelError, match=str(path)) as caught:
        shape.read_shape_file(path)
    if content.startswith(b"v"):
        assert "line 3: not a text shape model" in str(caught.value)


def test_face_index_out_of_range_names_line(tmp_path):
    path = tmp_path / "out_of_range.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n")
    with pytest.raises(ShapeModelError, match=r"out_of_range\.obj: line 5: face index out of range: \[1, 2, 4\]"):
        shape.read_shape_file(path)


def test_wrong_counts_name_the_model_key(cube_model, tmp_path):
    path = write_obj(tmp_path / "cube_part.obj", CUBE_VERTICES_KM, CUBE_FACES[:-2])
    with pytest.raises(ShapeModelError) as caught:
        shape.load_shape_model(path, "test_cube")
    message = str(caught.value)
    assert str(path) in message and "10 facets" in message and "12 facets" in message
    assert "not the model named by 'shape_model'" in message


def test_checksum_mismatch_gives_expected_and_got(cube_model, tmp_path):
    moved_km = CUBE_VERTICES_KM.copy()
    moved_km[6] += 0.001  # one corner moved by 1 m
    path = write_obj(tmp_path / "other_cube.obj", moved_km, CUBE_FACES)
    with pytest.raises(ShapeModelError) as caught:
        shape.load_shape_model(path, "test_cube")
    message = str(caught.value)
    expected = shape.SHAPE_MODELS["test_cube"].geometry_sha256
    got = shape.geometry_sha256(moved_km, CUBE_FACES)
    assert str(path) in message
    assert f"expected {expected}, got {got}" in message
    assert "not the model named by shape_model='test_cube'" in message


def test_open_mesh_is_refused(monkeypatch, tmp_path):
    open_faces = CUBE_FACES[:-1]
    register_model(monkeypatch, "test_open_cube", CUBE_VERTICES_KM, open_faces)
    path = write_obj(tmp_path / "open.obj", CUBE_VERTICES_KM, open_faces)
    with pytest.raises(ShapeModelError, match=r"open\.obj: the mesh is not closed.*only one facet"):
        shape.load_shape_model(path, "test_open_cube")


def test_inconsistent_winding_is_refused(monkeypatch, tmp_path):
    faces = CUBE_FACES.copy()
    faces[3] = faces[3, ::-1]
    register_model(monkeypatch, "test_flipped_facet", CUBE_VERTICES_KM, faces)
    path = write_obj(tmp_path / "flipped.obj", CUBE_VERTICES_KM, faces)
    with pytest.raises(ShapeModelError, match=r"flipped\.obj: the mesh is not closed and consistently oriented"):
        shape.load_shape_model(path, "test_flipped_facet")


def test_inward_mesh_is_refused(monkeypatch, tmp_path):
    inward_faces = CUBE_FACES[:, ::-1]
    register_model(monkeypatch, "test_inward_cube", CUBE_VERTICES_KM, inward_faces)
    path = write_obj(tmp_path / "inward.obj", CUBE_VERTICES_KM, inward_faces)
    with pytest.raises(ShapeModelError, match=r"inward\.obj: the facets are wound inward \(signed volume -0\.001"):
        shape.load_shape_model(path, "test_inward_cube")


# ---------------------------------------------------------------- facet geometry


def test_cube_facet_geometry_is_outward(cube_model):
    model = shape.load_shape_model(cube_model, "test_cube")
    centroids_m, normals, areas_m2 = shape.facet_geometry(model.vertices_m, model.faces)
    assert centroids_m.shape == normals.shape == (12, 3) and areas_m2.shape == (12,)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    # Outward: along the direction from the cube's centre to the facet, and axis-aligned.
    assert np.all(np.einsum("ij,ij->i", normals, centroids_m) > 0)
    np.testing.assert_allclose(np.abs(normals).max(axis=1), 1.0)
    np.testing.assert_allclose(areas_m2, 0.5 * 100.0**2)
    assert shape.signed_volume(model.vertices_m, model.faces) == pytest.approx(100.0**3)


def test_tetrahedron_facet_geometry():
    vertices_m = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    centroids_m, normals, areas_m2 = shape.facet_geometry(vertices_m, faces)
    np.testing.assert_allclose(normals[:3], [[0, 0, -1], [0, -1, 0], [-1, 0, 0]])
    np.testing.assert_allclose(normals[3], np.full(3, 1 / np.sqrt(3)))
    np.testing.assert_allclose(areas_m2, [2, 2, 2, 2 * np.sqrt(3)])
    np.testing.assert_allclose(centroids_m[3], [2 / 3, 2 / 3, 2 / 3])
    assert shape.mesh_closure_problem(faces, 4) is None
    assert shape.signed_volume(vertices_m, faces) == pytest.approx(8 / 6)


def test_degenerate_facet_has_zero_normal():
    vertices_m = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], dtype=np.float64)
    _, normals, areas_m2 = shape.facet_geometry(vertices_m, np.array([[0, 1, 2]]))
    np.testing.assert_array_equal(normals, 0.0)
    np.testing.assert_array_equal(areas_m2, 0.0)


# ---------------------------------------------------------------- download


def test_download_from_file_url(monkeypatch, tmp_path):
    source = write_gaskell(tmp_path / "cube_plates.tab", CUBE_VERTICES_KM, CUBE_FACES)
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES, urls=(source.as_uri(),))
    dest = tmp_path / "resources" / "cube.tab"
    assert shape.download_shape_model("test_cube", dest, retry_wait_s=0) == dest
    assert dest.read_bytes() == source.read_bytes()
    assert sorted(p.name for p in dest.parent.iterdir()) == ["cube.tab"]


def test_download_falls_back_to_mirror(monkeypatch, tmp_path):
    source = write_obj(tmp_path / "cube.obj", CUBE_VERTICES_KM, CUBE_FACES)
    missing = (tmp_path / "missing.obj").as_uri()
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES, urls=(missing, source.as_uri()))
    dest = tmp_path / "out" / "cube.obj"
    shape.download_shape_model("test_cube", dest, retries=2, retry_wait_s=0)
    assert sorted(p.name for p in dest.parent.iterdir()) == ["cube.obj"]


def test_download_bad_url_fails_without_leaving_files(monkeypatch, tmp_path):
    bad_url = (tmp_path / "no_such_file.tab").as_uri()
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES, urls=(bad_url,))
    dest_dir = tmp_path / "resources"
    with pytest.raises(ShapeModelError) as caught:
        shape.download_shape_model("test_cube", dest_dir / "cube.tab", retries=2, retry_wait_s=0)
    message = str(caught.value)
    assert bad_url in message and "attempt 2" in message
    assert "'shape_model_path'" in message
    assert list(dest_dir.iterdir()) == []


def test_download_of_wrong_model_is_rejected_without_leaving_files(monkeypatch, tmp_path):
    moved_km = CUBE_VERTICES_KM * 1.01
    wrong = write_obj(tmp_path / "wrong.obj", moved_km, CUBE_FACES)
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES, urls=(wrong.as_uri(),))
    dest_dir = tmp_path / "resources"
    with pytest.raises(ShapeModelError, match=r"downloaded but rejected.*checksum mismatch.*'shape_model_path'"):
        shape.download_shape_model("test_cube", dest_dir / "cube.tab", retry_wait_s=0)
    assert list(dest_dir.iterdir()) == []


def test_download_keeps_an_existing_file_on_failure(monkeypatch, tmp_path):
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES, urls=((tmp_path / "x").as_uri(),))
    dest = tmp_path / "cube.tab"
    dest.write_text("previous")
    with pytest.raises(ShapeModelError):
        shape.download_shape_model("test_cube", dest, retries=1)
    assert dest.read_text() == "previous"


# ---------------------------------------------------------------- prepared model and rule scripts


def test_write_prepared_model(itokawa_dir, tmp_path, caplog):
    out_npz = tmp_path / "prepared" / "gaskell_ver64q.npz"
    with caplog.at_level(logging.INFO, logger="asteroid_photometry.world.shape"):
        shape.write_prepared_model(itokawa_dir / "itokawa_low.obj", "gaskell_ver64q", out_npz)
    with np.load(out_npz) as prepared:
        assert set(prepared.files) == {
            "vertices_m", "faces", "centroids_m", "normals", "areas_m2", "geometry_sha256", "model_name"
        }
        assert prepared["vertices_m"].shape == (24578, 3)
        assert prepared["faces"].shape == (49152, 3) and prepared["faces"].dtype == np.int64
        assert prepared["centroids_m"].shape == prepared["normals"].shape == (49152, 3)
        assert prepared["areas_m2"].sum() == pytest.approx(0.39855e6, rel=2e-4)
        assert str(prepared["geometry_sha256"]) == shape.SHAPE_MODELS["gaskell_ver64q"].geometry_sha256
        assert str(prepared["model_name"]) == "gaskell_ver64q"
        # Normals point away from the centre of mass on average (outward).
        assert np.einsum("ij,ij->i", prepared["normals"], prepared["centroids_m"]).mean() > 0
    assert sorted(p.name for p in out_npz.parent.iterdir()) == ["gaskell_ver64q.npz"]
    assert "24578 vertices used, 49152 facets; extent 561.7 x 305.1 x 243.4 m" in caplog.text


@pytest.fixture
def restore_root_logging():
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    yield
    for handler in root.handlers:
        if handler not in handlers:
            handler.close()
    root.handlers[:] = handlers
    root.setLevel(level)


def run_rule_script(script_name, **snakemake_fields):
    runpy.run_path(str(SCRIPTS_DIR / script_name), init_globals={"snakemake": SimpleNamespace(**snakemake_fields)})


def test_rule_scripts(monkeypatch, tmp_path, restore_root_logging):
    source = write_obj(tmp_path / "cube.obj", CUBE_VERTICES_KM, CUBE_FACES)
    register_model(monkeypatch, "test_cube", CUBE_VERTICES_KM, CUBE_FACES, urls=(source.as_uri(),))
    model_path = tmp_path / "resources" / "cube.tab"
    npz_path = tmp_path / "results" / "cube.npz"
    run_rule_script(
        "fetch_shape_model.py",
        params=SimpleNamespace(model_name="test_cube"),
        output=SimpleNamespace(model=str(model_path)),
        log=[str(tmp_path / "fetch.log")],
    )
    run_rule_script(
        "prepare_shape.py",
        input=SimpleNamespace(model=str(model_path)),
        params=SimpleNamespace(model_name="test_cube"),
        output=SimpleNamespace(npz=str(npz_path)),
        log=[str(tmp_path / "prepare.log")],
    )
    with np.load(npz_path) as prepared:
        assert prepared["faces"].shape == (12, 3)
    assert "verified test_cube" in (tmp_path / "fetch.log").read_text()
    assert "8 vertices used, 12 facets" in (tmp_path / "prepare.log").read_text()
