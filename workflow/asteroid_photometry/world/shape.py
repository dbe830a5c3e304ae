"""Itokawa shape models: registry, parsers, verification and facet geometry.

The first stage of the flow. Both models ship with the workflow, xz-compressed,
in ``workflow/resources/shape/`` (their provenance and checksums are in the
``SOURCES.md`` there); ``fetch_shape_model`` downloads a model from the PDS
Small Bodies Node instead when asked to (``shape_model_source: download``), or
the user points ``shape_model_path`` at a copy of their own. ``prepare_shape``
verifies it and writes the facet table (centroids, outward normals, areas)
that rendering and observation read. Files may be xz- or gzip-compressed.

Two text formats are read, the format being detected from the content:

- Wavefront-OBJ-like: ``v x y z`` and ``f i j k`` lines, 1-based indices
  (``itokawa_low.obj`` and the PDS radar ``25143itokawa.tab``).
- Gaskell PDS plate model (``ver64q.tab``): a header ``NV NF`` (or ``NV``
  alone, with ``NF`` on its own line after the vertices), ``NV`` lines
  ``index x y z``, then ``NF`` lines ``index i j k``, 1-based.

Coordinates in the files are kilometres in the model's body frame (origin at
the centre of mass, +z the spin pole); loaded models hold metres
(``vertices_m``, float64) and 0-based ``faces`` (int64). Gaskell models list
vertices that no facet uses (duplicates on the cube-face seams of the ICQ
grid); they are kept on load and dropped by :func:`compact_mesh`.

A model is identified by :func:`geometry_sha256`, a checksum of the parsed
geometry rather than of the file bytes, so the same model gives the same
checksum in either format, with or without its unused vertices.
"""

from __future__ import annotations

import dataclasses
import gzip
import hashlib
import logging
import lzma
import os
import tempfile
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

import numpy as np

logger = logging.getLogger(__name__)

# The compressed copies of the registry's models that ship with the workflow.
SHIPPED_SHAPE_DIR = Path(__file__).resolve().parents[2] / "resources" / "shape"

METRES_PER_KM = 1000.0
#: Itokawa's rotation period (hours), which a mission knows: the image times of a set that turns once in ``n_images``
#: steps (rule ``mission``), and each image's rotation phase from its time (``experiments.table2``).
ROTATION_PERIOD_H = 12.132
# Checksum quantum: 1e-6 km (1 mm). Both archives give coordinates to at most
# 1e-6 km (Gaskell to 1e-5 km, Ostro's E14.6 values to 1e-6 km), so rounding
# to this quantum is lossless and never meets a half-way tie.
CHECKSUM_UNITS_PER_KM = 1_000_000

CONFIG_KEY_MODEL = "shape_model"
CONFIG_KEY_PATH = "shape_model_path"

DOWNLOAD_TIMEOUT_S = 60.0
# The SBN web server has been reported to refuse clients without a
# browser-like user agent.
_USER_AGENT = "Mozilla/5.0 (compatible; asteroid_photometry shape-model fetch)"


class ShapeModelError(ValueError):
    """A shape model that cannot be read, is not the model asked for, or is not a closed outward mesh."""


@dataclass(frozen=True)
class ShapeModelSpec:
    """One entry of :data:`SHAPE_MODELS`: what the model is, where it lives, and how to recognise it.

    ``urls`` are tried in order; the first is the PDS3 product the data set
    name refers to, later ones are mirrors. ``n_vertices_used`` is the number
    of vertices the facets reference (a re-export may carry only those).
    """

    name: str
    description: str
    citation: str
    file_name: str
    urls: tuple[str, ...]
    n_vertices: int
    n_vertices_used: int
    n_facets: int
    geometry_sha256: str
    shipped_file: str

    @property
    def shipped_path(self) -> Path:
        """The compressed copy that ships with the workflow (workflow/resources/shape/)."""
        return SHIPPED_SHAPE_DIR / self.shipped_file


# URLs: the tools here cannot reach the archive, so none was fetched. The PDS3
# paths follow public code that downloads from them: the radar path and the
# Gaskell `data/` folder appear in several independent projects (high
# confidence); `data/vertex/ver64q.tab` appears in one and matches the layout
# of the Eros Gaskell data set (medium-high confidence). The PDS4 mirrors
# (the 2020 migrations `compil.ast.radar.shape-models` and
# `gaskell.ast-itokawa.shape-model_V1_1`) follow the layout other products in
# those bundles are fetched from (medium confidence). Every download is
# checked against `geometry_sha256`, so a wrong or changed file is refused.
SHAPE_MODELS: dict[str, ShapeModelSpec] = {
    "gaskell_ver64q": ShapeModelSpec(
        name="gaskell_ver64q",
        description=(
            "Gaskell Itokawa shape model V1.0, ICQ q = 64 (ver64q): stereophotoclinometry "
            "from Hayabusa AMICA images; 25350 vertices (772 unused seam duplicates), "
            "49152 triangular facets, km, body frame with +z the spin pole."
        ),
        citation=(
            "Gaskell, R., Saito, J., Ishiguro, M., Kubota, T., Hashimoto, T., Hirata, N., "
            "Abe, S., Barnouin-Jha, O., and Scheeres, D., Gaskell Itokawa Shape Model V1.0, "
            "HAY-A-AMICA-5-ITOKAWASHAPE-V1.0, NASA Planetary Data System, 2008."
        ),
        file_name="ver64q.tab",
        urls=(
            "https://sbnarchive.psi.edu/pds3/hayabusa/HAY_A_AMICA_5_ITOKAWASHAPE_V1_0/data/vertex/ver64q.tab",
            "https://sbnarchive.psi.edu/pds4/non_mission/gaskell.ast-itokawa.shape-model_V1_1/data/vertex/ver64q.tab",
        ),
        n_vertices=25350,
        n_vertices_used=24578,
        n_facets=49152,
        geometry_sha256="90e2e9e351021db8f1d993c3ad83b73ac76060329ec485864df5015ae9078f02",
        shipped_file="gaskell_ver64q.obj.xz",
    ),
    "ostro_radar": ShapeModelSpec(
        name="ostro_radar",
        description=(
            "Ostro et al. (2004) radar shape model of 25143 Itokawa from Goldstone delay-Doppler "
            "images: 6098 vertices, 12192 triangular facets, km, principal-axis frame with the "
            "origin at the centre of mass."
        ),
        citation=(
            "Ostro, S.J., et al., Asteroid Radar Shape Models, 25143 Itokawa, "
            "EAR-A-5-DDR-RADARSHAPE-MODELS-V2.0:RSHAPES-25143ITOKAWA-200405, NASA Planetary Data "
            "System, 2004; Ostro, S.J., et al. (2004), Radar observations of asteroid 25143 "
            "Itokawa (1998 SF36), Meteoritics & Planetary Science 39, 407-424."
        ),
        file_name="25143itokawa.tab",
        urls=(
            "https://sbnarchive.psi.edu/pds3/non_mission/EAR_A_5_DDR_RADARSHAPE_MODELS_V2_0/data/25143itokawa.tab",
            "https://sbnarchive.psi.edu/pds4/non_mission/compil.ast.radar.shape-models/data/25143itokawa.tab",
        ),
        n_vertices=6098,
        n_vertices_used=6098,
        n_facets=12192,
        geometry_sha256="7ed3c0b73a406b0dfd2a202679a82c2b10e7180da233d42ac61bd553f0db5a17",
        shipped_file="ostro_radar.tab.xz",
    ),
}
DEFAULT_SHAPE_MODEL = "gaskell_ver64q"


@dataclass(frozen=True, eq=False)
class ShapeModel:
    """A loaded shape model in the body frame: vertices in metres, 0-based triangular faces.

    ``vertices_m`` may hold vertices that no face uses; :meth:`compacted`
    drops them. ``geometry_sha256`` is :func:`geometry_sha256` of the geometry.
    """

    name: str
    vertices_m: np.ndarray
    faces: np.ndarray
    geometry_sha256: str
    source_path: Path

    def compacted(self) -> ShapeModel:
        """The same model without unused vertices (faces remapped, vertex order kept)."""
        vertices_m, faces, _ = compact_mesh(self.vertices_m, self.faces)
        return dataclasses.replace(self, vertices_m=vertices_m, faces=faces)


def get_shape_model_spec(model_name: str) -> ShapeModelSpec:
    """The registry entry for ``model_name``, or a :class:`ShapeModelError` naming the config key."""
    try:
        return SHAPE_MODELS[model_name]
    except KeyError:
        known = ", ".join(sorted(SHAPE_MODELS))
        raise ShapeModelError(
            f"unknown shape model {model_name!r} (config key {CONFIG_KEY_MODEL!r}); known models: {known}"
        ) from None


# ---------------------------------------------------------------- parsing

# OBJ statements that carry nothing this workflow uses and are skipped.
_OBJ_IGNORED = frozenset({"vn", "vt", "vp", "o", "g", "s", "usemtl", "mtllib", "l"})


def _numbered_lines(text: str):
    """(line number, tokens) for each non-blank, non-comment line; CRLF and LF both accepted."""
    for line_number, line in enumerate(text.split("\n"), start=1):
        tokens = line.split("#", 1)[0].split()
        if tokens:
            yield line_number, tokens


def _garbled(path, line_number, problem) -> ShapeModelError:
    return ShapeModelError(f"{path}: line {line_number}: {problem}")


def _parse_obj(path, lines) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    vertices_km, faces, face_lines = [], [], []
    for line_number, tokens in lines:
        keyword = tokens[0]
        if keyword == "v":
            if len(tokens) < 4:
                raise _garbled(path, line_number, f"vertex needs 3 coordinates, got {' '.join(tokens)!r}")
            try:
                vertices_km.append([float(t) for t in tokens[1:4]])
            except ValueError:
                raise _garbled(path, line_number, f"vertex coordinates are not numbers: {' '.join(tokens)!r}") from None
        elif keyword == "f":
            if len(tokens) != 4:
                raise _garbled(
                    path, line_number, f"only triangular facets are supported, got {len(tokens) - 1} vertices"
                )
            try:
                # "f 1/4/2 ..." carries texture/normal indices after the vertex index.
                faces.append([int(t.split("/", 1)[0]) for t in tokens[1:]])
            except ValueError:
                raise _garbled(path, line_number, f"facet indices are not integers: {' '.join(tokens)!r}") from None
            face_lines.append(line_number)
        elif keyword not in _OBJ_IGNORED:
            raise _garbled(path, line_number, f"unexpected OBJ statement {keyword!r}")
    return (
        np.array(vertices_km, dtype=np.float64).reshape(-1, 3),
        np.array(faces, dtype=np.int64).reshape(-1, 3),
        np.array(face_lines, dtype=np.int64),
    )


def _parse_int(path, line_number, token, what) -> int:
    try:
        return int(token)
    except ValueError:
        raise _garbled(path, line_number, f"{what} is not an integer: {token!r}") from None


def _parse_gaskell(path, lines) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lines = iter(lines)
    header_line, header = next(lines)
    n_vertices = _parse_int(path, header_line, header[0], "vertex count")
    n_facets = _parse_int(path, header_line, header[1], "plate count") if len(header) == 2 else None

    def table(n_rows, what, convert):
        rows, row_lines = [], []
        for expected_index in range(1, n_rows + 1):
            try:
                line_number, tokens = next(lines)
            except StopIteration:
                raise ShapeModelError(
                    f"{path}: the file ends after {what} {expected_index - 1} of {n_rows} "
                    "announced in the header; it is truncated or the counts are wrong"
                ) from None
            if len(tokens) != 4:
                raise _garbled(path, line_number, f"{what} row needs 'index a b c', got {' '.join(tokens)!r}")
            index = _parse_int(path, line_number, tokens[0], f"{what} index")
            if index != expected_index:
                raise _garbled(path, line_number, f"{what} index {index} out of sequence, expected {expected_index}")
            try:
                rows.append([convert(t) for t in tokens[1:]])
            except ValueError:
                raise _garbled(path, line_number, f"{what} values are not numbers: {' '.join(tokens)!r}") from None
            row_lines.append(line_number)
        return rows, row_lines

    vertices_km, _ = table(n_vertices, "vertex", float)
    if n_facets is None:
        try:
            count_line, tokens = next(lines)
        except StopIteration:
            raise ShapeModelError(f"{path}: the file ends after the vertices; the plate count is missing") from None
        if len(tokens) != 1:
            raise _garbled(path, count_line, f"expected the plate count, got {' '.join(tokens)!r}")
        n_facets = _parse_int(path, count_line, tokens[0], "plate count")
    faces, face_lines = table(n_facets, "plate", int)
    for line_number, tokens in lines:
        raise _garbled(path, line_number, f"unexpected content after the last of {n_facets} plates")
    return (
        np.array(vertices_km, dtype=np.float64).reshape(-1, 3),
        np.array(faces, dtype=np.int64).reshape(-1, 3),
        np.array(face_lines, dtype=np.int64),
    )


def parse_shape_text(text: str, path="<text>") -> tuple[np.ndarray, np.ndarray]:
    """Parse a model in either text format (detected from content) into (vertices_km (V,3), faces (F,3) 0-based).

    Checks that every face index refers to an existing vertex; unused
    vertices are kept. Errors are :class:`ShapeModelError` naming ``path``
    and the line.
    """
    lines = list(_numbered_lines(text))
    if not lines:
        raise ShapeModelError(f"{path}: the file is empty; expected a shape model")
    first_line, first_tokens = lines[0]
    if first_tokens[0] == "v" or first_tokens[0] == "f" or first_tokens[0] in _OBJ_IGNORED:
        vertices_km, faces_1based, face_lines = _parse_obj(path, lines)
    elif len(first_tokens) in (1, 2) and all(t.isdigit() for t in first_tokens):
        vertices_km, faces_1based, face_lines = _parse_gaskell(path, lines)
    else:
        raise _garbled(
            path,
            first_line,
            f"neither an OBJ-like model ('v x y z' / 'f i j k') nor a Gaskell plate model "
            f"(header 'NV NF'): {' '.join(first_tokens)[:60]!r}",
        )
    if len(vertices_km) == 0 or len(faces_1based) == 0:
        raise ShapeModelError(
            f"{path}: no {'vertices' if len(vertices_km) == 0 else 'facets'} found; expected a shape model"
        )
    if not np.all(np.isfinite(vertices_km)):
        raise ShapeModelError(f"{path}: vertex coordinates include NaN or infinity")
    out_of_range = (faces_1based < 1) | (faces_1based > len(vertices_km))
    if out_of_range.any():
        bad_face = int(np.flatnonzero(out_of_range.any(axis=1))[0])
        raise _garbled(
            path,
            int(face_lines[bad_face]),
            f"face index out of range: {faces_1based[bad_face].tolist()} with {len(vertices_km)} vertices "
            "(indices are 1-based)",
        )
    return vertices_km, faces_1based - 1


def _decompressed(data: bytes, path) -> bytes:
    """``data`` itself, or its content when it is xz- or gzip-compressed (recognised by magic bytes)."""
    try:
        if data[:6] == b"\xfd7zXZ\x00":
            return lzma.decompress(data)
        if data[:2] == b"\x1f\x8b":
            return gzip.decompress(data)
    except (lzma.LZMAError, OSError, EOFError) as error:
        raise ShapeModelError(f"{path}: cannot decompress the shape model file: {error}") from None
    return data


def read_shape_file(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a model file: (vertices_km (V,3) float64, faces (F,3) int64 0-based). See :func:`parse_shape_text`."""
    path = Path(path)
    if not path.is_file():
        raise ShapeModelError(
            f"{path}: shape model file not found; set {CONFIG_KEY_PATH!r} to an existing copy, "
            "or to null to download it"
        )
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ShapeModelError(f"{path}: cannot read the shape model file: {error}") from error
    data = _decompressed(data, path)
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as error:
        line_number = data.count(b"\n", 0, error.start) + 1
        raise _garbled(path, line_number, "not a text shape model (non-ASCII bytes)") from None
    return parse_shape_text(text, path)


# ---------------------------------------------------------------- geometry


def compact_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop vertices no face uses, keeping vertex order.

    Returns (vertices_kept, faces_remapped, kept_index) where ``kept_index``
    gives each kept vertex's index in the input. Works in any length unit.
    """
    faces = np.asarray(faces, dtype=np.int64)
    kept_index = np.unique(faces)
    new_index = np.full(len(vertices), -1, dtype=np.int64)
    new_index[kept_index] = np.arange(len(kept_index), dtype=np.int64)
    return np.asarray(vertices)[kept_index], new_index[faces], kept_index


def geometry_sha256(vertices_km, faces) -> str:
    """Checksum of a model's geometry, independent of the file format it came in.

    The mesh is compacted (:func:`compact_mesh`), coordinates are rounded to
    integer units of 1e-6 km, and sha256 is taken over, in order: the shapes
    ``(V, 3, F, 3)``, the rounded coordinates and the 0-based faces, all as
    little-endian int64 in C order.
    """
    vertices_km, faces, _ = compact_mesh(np.asarray(vertices_km, dtype=np.float64), faces)
    coords = np.rint(vertices_km * CHECKSUM_UNITS_PER_KM).astype("<i8")
    digest = hashlib.sha256()
    digest.update(np.array([*coords.shape, *faces.shape], dtype="<i8").tobytes())
    digest.update(np.ascontiguousarray(coords).tobytes())
    digest.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    return digest.hexdigest()


def facet_geometry(vertices_m, faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-facet centroids_m (F,3), unit normals (F,3) and areas_m2 (F,), in the body frame.

    Normals follow the right-hand rule over the face's vertex order, which
    points outward for the verified (counter-clockwise) models. A degenerate
    facet gets area 0 and a zero normal.
    """
    corners_m = np.asarray(vertices_m, dtype=np.float64)[np.asarray(faces)]  # (F, 3 corners, 3 xyz)
    centroids_m = corners_m.mean(axis=1)
    cross_m2 = np.cross(corners_m[:, 1] - corners_m[:, 0], corners_m[:, 2] - corners_m[:, 0])
    twice_areas_m2 = np.linalg.norm(cross_m2, axis=1)
    normals = np.divide(
        cross_m2, twice_areas_m2[:, None], out=np.zeros_like(cross_m2), where=twice_areas_m2[:, None] > 0
    )
    return centroids_m, normals, 0.5 * twice_areas_m2


def signed_volume(vertices, faces) -> float:
    """Signed volume enclosed by a triangle mesh (cube of the vertices' unit); > 0 for outward facets."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])).sum() / 6.0)


def mesh_closure_problem(faces, n_vertices) -> str | None:
    """Why a triangle mesh is not closed and consistently oriented, or None if it is.

    Closed and consistently oriented means each directed edge occurs once
    and its reverse occurs too, so every edge joins exactly two facets that
    agree on orientation.
    """
    faces = np.asarray(faces, dtype=np.int64)
    repeats_vertex = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    if repeats_vertex.any():
        return f"facet {int(np.argmax(repeats_vertex)) + 1} repeats a vertex"
    tails = faces.reshape(-1)
    heads = np.roll(faces, -1, axis=1).reshape(-1)
    edge_codes = tails * n_vertices + heads
    unique_codes, counts = np.unique(edge_codes, return_counts=True)
    if np.any(counts > 1):
        code = int(unique_codes[np.argmax(counts > 1)])
        return (
            f"edge {code // n_vertices + 1}-{code % n_vertices + 1} is used twice in the same direction "
            "(facets wound inconsistently, or more than two facets on an edge)"
        )
    missing = ~np.isin(heads * n_vertices + tails, unique_codes)
    if missing.any():
        edge = int(np.flatnonzero(missing)[0])
        return f"edge {tails[edge] + 1}-{heads[edge] + 1} borders only one facet (the mesh has a hole)"
    return None


def check_closed_outward(vertices_km, faces, path) -> None:
    """Raise :class:`ShapeModelError` unless the mesh is closed, consistently oriented and outward."""
    problem = mesh_closure_problem(faces, len(vertices_km))
    if problem is not None:
        raise ShapeModelError(f"{path}: the mesh is not closed and consistently oriented: {problem}")
    volume_km3 = signed_volume(vertices_km, faces)
    if not volume_km3 > 0:
        raise ShapeModelError(
            f"{path}: the facets are wound inward (signed volume {volume_km3:.6g} km^3 is not positive); "
            "expected counter-clockwise facets seen from outside"
        )


# ---------------------------------------------------------------- loading


def load_shape_model(path, model_name: str = DEFAULT_SHAPE_MODEL) -> ShapeModel:
    """Read ``path`` and verify it is the model ``model_name`` of :data:`SHAPE_MODELS`.

    Checks, in order: the file exists and parses, face indices are in range,
    the vertex and facet counts match the registry, the mesh is closed and
    outward-oriented, and the geometry checksum matches. Any failure is a
    :class:`ShapeModelError` naming the file and, where it helps, the config
    key. Unused vertices are kept (see :meth:`ShapeModel.compacted`).
    """
    spec = get_shape_model_spec(model_name)
    path = Path(path)
    vertices_km, faces = read_shape_file(path)
    if len(faces) != spec.n_facets or len(vertices_km) not in (spec.n_vertices, spec.n_vertices_used):
        raise ShapeModelError(
            f"{path}: has {len(vertices_km)} vertices and {len(faces)} facets, but {CONFIG_KEY_MODEL}="
            f"{model_name!r} has {spec.n_vertices} vertices ({spec.n_vertices_used} used) and "
            f"{spec.n_facets} facets; the file is truncated or is not the model named by "
            f"{CONFIG_KEY_MODEL!r} (check {CONFIG_KEY_PATH!r})"
        )
    check_closed_outward(vertices_km, faces, path)
    checksum = geometry_sha256(vertices_km, faces)
    if checksum != spec.geometry_sha256:
        raise ShapeModelError(
            f"{path}: geometry checksum mismatch: expected {spec.geometry_sha256}, got {checksum}; "
            f"the file is not the model named by {CONFIG_KEY_MODEL}={model_name!r} "
            f"(check {CONFIG_KEY_PATH!r})"
        )
    return ShapeModel(
        name=model_name,
        vertices_m=vertices_km * METRES_PER_KM,
        faces=faces,
        geometry_sha256=checksum,
        source_path=path,
    )


# ---------------------------------------------------------------- download


def _fetch_to(url: str, part_path: Path) -> None:
    request = urllib.request.Request(url, headers={"User-Agent": _USER_AGENT})
    with urllib.request.urlopen(request, timeout=DOWNLOAD_TIMEOUT_S) as response, part_path.open("wb") as part:
        while chunk := response.read(1 << 20):
            part.write(chunk)


def download_shape_model(model_name: str, dest_path, retries: int = 3, retry_wait_s: float = 2.0) -> Path:
    """Download ``model_name`` to ``dest_path``, verified, or raise :class:`ShapeModelError`.

    Each URL of the registry entry is tried in turn, up to ``retries`` times
    for network errors (waiting ``retry_wait_s`` doubling). The file is
    written beside ``dest_path`` under a temporary name, parsed and checked
    against the registry checksum, and only then renamed into place, so
    ``dest_path`` is either the verified model or absent.
    """
    spec = get_shape_model_spec(model_name)
    dest_path = Path(dest_path)
    dest_path.parent.mkdir(parents=True, exist_ok=True)
    failures = []
    for url in spec.urls:
        for attempt in range(1, max(retries, 1) + 1):
            handle, part_name = tempfile.mkstemp(prefix=f".{dest_path.name}.", suffix=".part", dir=dest_path.parent)
            os.close(handle)
            part_path = Path(part_name)
            try:
                logger.info("downloading %s (%s), attempt %d: %s", model_name, spec.file_name, attempt, url)
                _fetch_to(url, part_path)
                load_shape_model(part_path, model_name)
                os.replace(part_path, dest_path)
                logger.info("verified %s and saved it to %s", model_name, dest_path)
                return dest_path
            except ShapeModelError as error:
                # The content is wrong: fetching it again will not help.
                failures.append(f"{url}: downloaded but rejected: {error}")
                break
            except (urllib.error.URLError, OSError, ValueError) as error:
                failures.append(f"{url} (attempt {attempt}): {error}")
                permanent = isinstance(error, urllib.error.HTTPError) and 400 <= error.code < 500
                if permanent or isinstance(error, ValueError) or attempt >= retries:
                    break
                time.sleep(retry_wait_s * 2 ** (attempt - 1))
            finally:
                part_path.unlink(missing_ok=True)
    raise ShapeModelError(
        f"could not download shape model {model_name!r} ({spec.file_name}) to {dest_path}:\n  "
        + "\n  ".join(failures)
        + f"\nIf you have a copy of {spec.file_name}, set {CONFIG_KEY_PATH!r} in the config to its path."
    )


# ---------------------------------------------------------------- prepared model


def write_prepared_model(model_path, model_name: str, out_npz) -> Path:
    """Verify the model at ``model_path``, compact it and write the facet table to ``out_npz``.

    The .npz holds ``vertices_m`` (V,3), ``faces`` (F,3) 0-based,
    ``centroids_m`` (F,3), ``normals`` (F,3) unit outward, ``areas_m2`` (F,),
    all in the body frame, and the strings ``geometry_sha256`` and
    ``model_name``. Written under a temporary name and renamed into place.
    """
    model = load_shape_model(model_path, model_name).compacted()
    centroids_m, normals, areas_m2 = facet_geometry(model.vertices_m, model.faces)
    extent_m = model.vertices_m.max(axis=0) - model.vertices_m.min(axis=0)
    logger.info(
        "%s from %s: %d vertices used, %d facets; extent %.1f x %.1f x %.1f m; area %.0f m^2; "
        "volume %.0f m^3; geometry sha256 %s",
        model_name,
        model.source_path,
        len(model.vertices_m),
        len(model.faces),
        *extent_m,
        areas_m2.sum(),
        signed_volume(model.vertices_m, model.faces),
        model.geometry_sha256,
    )
    out_npz = Path(out_npz)
    out_npz.parent.mkdir(parents=True, exist_ok=True)
    handle, part_name = tempfile.mkstemp(prefix=f".{out_npz.name}.", suffix=".part", dir=out_npz.parent)
    try:
        with os.fdopen(handle, "wb") as part:
            np.savez(
                part,
                vertices_m=model.vertices_m,
                faces=model.faces,
                centroids_m=centroids_m,
                normals=normals,
                areas_m2=areas_m2,
                geometry_sha256=np.str_(model.geometry_sha256),
                model_name=np.str_(model_name),
            )
        os.replace(part_name, out_npz)
    finally:
        Path(part_name).unlink(missing_ok=True)
    return out_npz


def load_shape_npz(path) -> dict:
    with np.load(path) as data:
        return {name: data[name] for name in data.files}
