"""Rendering: the Minnaert BSDF as a Mitsuba 3 plugin, and the images of one set.

A Minnaert surface, ``f_r = albedo / pi * (cos_i cos_o)^(k - 1)``, lit by a
directional emitter of irradiance ``pi``, sends out the radiance
``b = albedo cos_i^k cos_o^(k - 1)``; a linear float image stores ``b`` per
pixel. The camera and the Sun are fixed; for each image the body's vertices
are turned into the camera's orientation (``R X_body``) around the body
centre, which is the world origin, and the camera sits at ``-t``. Only direct light is rendered (the paper's
setting): the ``direct`` integrator with one emitter sample per camera
sample, so cast shadows are there and inter-reflections are not. The pixel
filter is a box, so a pixel is the plain average of the radiance over its
footprint, and a pixel that lies entirely on one flat facet is exact up to the
Monte Carlo scatter of the view direction inside the pixel (random rays,
``pixel_sampling="area"``). ``pixel_sampling="centre"`` instead sends one ray
through each pixel's centre: a pure pixel then holds the law exactly along the
view direction that the observations give it (the model-mismatch sets).

Albedo and k are either one value for the whole body (the paper's
setting) or one value per facet (``surface_maps``). Per-facet values ride
on the mesh as the face attributes ``face_albedo`` and ``face_minnaert_k``,
which the BSDF reads at each hit with ``Shape.eval_attribute_1``; the
scalar path keeps its constants in the BSDF, as before.

Variants: ``cuda_ad_rgb`` where a GPU works, else ``llvm_ad_rgb`` (needs a
recent LLVM, see docs/running.md, "Rendering backends"), else ``scalar_rgb`` with a warning in the log: it
runs the Python BSDF once per sample and is about 100 times slower.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from asteroid_photometry.core import files
from asteroid_photometry.world.cameras import ImagingGeometry

log = logging.getLogger(__name__)

#: How a pixel is sampled: ``area``, ``spp`` random rays (the average over the
#: footprint); ``centre``, one ray through the pixel's centre.
PIXEL_SAMPLINGS = ("area", "centre")

DEFAULT_LLVM_PATHS = ("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1", "/usr/lib/aarch64-linux-gnu/libLLVM.so.19.1")
VARIANT_PREFERENCE = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
# Face attributes of the mesh that carry per-facet albedo and k.
ALBEDO_ATTRIBUTE = "face_albedo"
MINNAERT_K_ATTRIBUTE = "face_minnaert_k"

_PROBE = """
import mitsuba as mi, drjit as dr, sys
mi.set_variant(sys.argv[1])
x = dr.maximum(mi.Float([1.0, 2.0]), 1.5) * 2.0
assert [float(v) for v in x] == [3.0, 4.0]
"""


def _with_llvm_path(env: dict) -> dict:
    if "DRJIT_LIBLLVM_PATH" not in env:
        for candidate in DEFAULT_LLVM_PATHS:
            if Path(candidate).exists():
                env["DRJIT_LIBLLVM_PATH"] = candidate
                break
    return env


def variant_works(variant: str) -> bool:
    """Whether ``variant`` runs a JIT kernel, tried in a child process.

    An unsuitable LLVM aborts the process rather than raising, so the probe
    cannot run in this one.
    """
    env = _with_llvm_path(dict(os.environ))
    try:
        probe = subprocess.run([sys.executable, "-c", _PROBE, variant], env=env, capture_output=True, timeout=120)
    except subprocess.TimeoutExpired:
        return False
    if probe.returncode != 0:
        log.info("Mitsuba variant %s is not usable here: %s", variant, probe.stderr.decode(errors="replace").strip()[-300:])
    return probe.returncode == 0


#: Fewest threads Dr.Jit's pool may have: with one, writing an EXR (``mi.Bitmap.write``) waits forever for a
#: worker (seen with Mitsuba 3.9.1 on llvm_ad_rgb: a render job given one core by ``snakemake --cores 1`` hung
#: after its first image). A second thread costs a one-core job nothing but the writer's share.
MIN_RENDER_THREADS = 2


def set_render_threads(threads) -> None:
    """Dr.Jit's thread pool for a job given ``threads`` cores, never fewer than ``MIN_RENDER_THREADS``."""
    import drjit as dr

    dr.set_thread_count(max(int(threads), MIN_RENDER_THREADS))


def choose_variant(requested: str = "auto") -> str:
    """The Mitsuba variant to render with: the one asked for, or the fastest that works."""
    import mitsuba as mi

    _with_llvm_path(os.environ)
    available = set(mi.variants())
    if requested != "auto":
        if requested not in available or (requested != "scalar_rgb" and not variant_works(requested)):
            raise RuntimeError(
                f"config key 'mitsuba_variant': {requested!r} does not work on this machine "
                f"(built variants: {sorted(available)}); use 'auto'"
            )
        return requested
    for variant in VARIANT_PREFERENCE:
        if variant in available and (variant == "scalar_rgb" or variant_works(variant)):
            if variant == "scalar_rgb":
                log.warning(
                    "Falling back to Mitsuba's scalar_rgb variant: no working JIT backend (install Debian's "
                    "libllvm19 and set DRJIT_LIBLLVM_PATH). Rendering will be about 100x slower."
                )
            return variant
    raise RuntimeError("no Mitsuba variant works on this machine")


def one_sided_diffuse_bsdf():
    """A base class for the current Mitsuba variant: a one-sided reflectance, sampled on the cosine hemisphere.

    A subclass defines ``_value_times_cos(si, wo, active)``, ``f_r cos_i`` with
    ``si.wi`` towards the camera and ``wo`` towards the light; this class gives
    Mitsuba its ``sample``, ``eval`` and ``pdf``. Must be called after
    ``mitsuba.set_variant``.
    """
    import drjit as dr
    import mitsuba as mi

    class OneSidedDiffuseBSDF(mi.BSDF):
        def sample(self, ctx, si, sample1, sample2, active):
            bs = mi.BSDFSample3f()
            bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            value = self._value_times_cos(si, bs.wo, active)
            weight = dr.select(bs.pdf > 0.0, value / bs.pdf, 0.0)
            return bs, mi.Color3f(weight)

        def eval(self, ctx, si, wo, active):
            return mi.Color3f(self._value_times_cos(si, wo, active))

        def pdf(self, ctx, si, wo, active):
            front = (mi.Frame3f.cos_theta(si.wi) > 0.0) & (mi.Frame3f.cos_theta(wo) > 0.0)
            return dr.select(front, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            pass

    return OneSidedDiffuseBSDF


def register_minnaert_plugin():
    """Define the Minnaert BSDF for the current Mitsuba variant and register it as ``minnaert``.

    Must be called after ``mitsuba.set_variant``; returns the class.
    """
    import drjit as dr
    import mitsuba as mi

    class MinnaertBSDF(one_sided_diffuse_bsdf()):
        """``f_r = albedo / pi * (cos_i cos_o)^(k - 1)``, one-sided, reciprocal.

        Its own Dr.Jit expression of the Minnaert law (the numpy one is
        ``reflectance.laws.minnaert_brightness``).
        """

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.albedo = float(props.get("albedo", 0.5))
            self.minnaert_k = float(props.get("minnaert_k", 1.0))
            # Per facet: read the mesh's face attributes instead of the two constants.
            self.per_facet = bool(props.get("per_facet", False))
            flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags

        def _value_times_cos(self, si, wo, active):
            # si.wi points to the camera (cos_o), wo to the light (cos_i);
            # Mitsuba's eval includes the foreshortening cos_i.
            cos_o = mi.Frame3f.cos_theta(si.wi)
            cos_i = mi.Frame3f.cos_theta(wo)
            valid = active & (cos_o > 0.0) & (cos_i > 0.0)
            if self.per_facet:
                albedo = si.shape.eval_attribute_1(ALBEDO_ATTRIBUTE, si, valid)
                minnaert_k = si.shape.eval_attribute_1(MINNAERT_K_ATTRIBUTE, si, valid)
            else:
                albedo, minnaert_k = self.albedo, self.minnaert_k
            value = albedo * dr.inv_pi * dr.power(cos_i * cos_o, minnaert_k - 1.0) * cos_i
            return dr.select(valid, value, 0.0)

        def to_string(self):
            if self.per_facet:
                return f"MinnaertBSDF[albedo={ALBEDO_ATTRIBUTE}, minnaert_k={MINNAERT_K_ATTRIBUTE} (per facet)]"
            return f"MinnaertBSDF[albedo={self.albedo}, minnaert_k={self.minnaert_k}]"

    mi.register_bsdf("minnaert", lambda props: MinnaertBSDF(props))
    return MinnaertBSDF


def setup_mitsuba(requested_variant: str = "auto") -> str:
    """Choose and set the variant, register the plugin; returns the variant name."""
    import mitsuba as mi

    variant = choose_variant(requested_variant)
    mi.set_variant(variant)
    register_minnaert_plugin()
    from asteroid_photometry.world.plugins import register_photometric_plugin

    register_photometric_plugin()
    log.info("Mitsuba %s, variant %s", mi.__version__, variant)
    return variant


def _mitsuba_camera_to_world(camera_translation: np.ndarray):
    """Camera-to-world transform of the Mitsuba sensor.

    The world is the camera frame shifted to the body centre (``X_world =
    X_cam - t``), so vertex coordinates stay small and float32 keeps the
    facet normals accurate to ~1e-7. Mitsuba's camera looks along +z with
    +x left and +y up; ours has +x right and +y down, hence the flip.
    """
    import mitsuba as mi

    return mi.ScalarTransform4f().translate((-np.asarray(camera_translation, float)).tolist()) @ mi.ScalarTransform4f().scale([-1.0, -1.0, 1.0])


def _sampler(spp: int, pixel_sampling: str) -> dict:
    if pixel_sampling == "area":
        return {"type": "independent", "sample_count": int(spp)}
    if pixel_sampling == "centre":
        if int(spp) != 1:
            raise ValueError(f"pixel_sampling 'centre' sends one ray per pixel; got {spp} samples per pixel")
        # The stratified sampler without jitter puts its one sample at the centre of its one stratum, the pixel.
        return {"type": "stratified", "sample_count": 1, "jitter": False}
    raise ValueError(f"pixel_sampling {pixel_sampling!r} is not one of {PIXEL_SAMPLINGS}")


def scene_dict(geometry: ImagingGeometry, light_dir_cam: np.ndarray, spp: int, body: dict, pixel_sampling: str = "area") -> dict:
    """A Mitsuba scene in the camera frame: perspective camera at the origin, directional Sun, ``body``."""
    intrinsics = geometry.intrinsics
    if intrinsics.width != intrinsics.height or abs(intrinsics.cx - intrinsics.width / 2) > 1e-9:
        raise ValueError("the renderer supports square images with a centred principal point only")
    distance = geometry.camera_distance_m
    translations = geometry.body_to_camera[:, :3, 3]
    if not np.allclose(translations, translations[0]):
        raise ValueError("the renderer expects a fixed camera: every body_to_camera must share its translation")
    return {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective",
            "fov": intrinsics.fov_x_deg,
            "fov_axis": "x",
            "near_clip": max(distance * 0.01, 1e-3),
            "far_clip": distance * 10.0,
            "to_world": _mitsuba_camera_to_world(translations[0]),
            "film": {
                "type": "hdrfilm",
                "width": intrinsics.width,
                "height": intrinsics.height,
                "pixel_format": "luminance",
                "component_format": "float32",
                "rfilter": {"type": "box"},
            },
            "sampler": _sampler(spp, pixel_sampling),
        },
        # ``direction`` is where the light travels: away from the Sun.
        "sun": {"type": "directional", "direction": (-np.asarray(light_dir_cam, float)).tolist(), "irradiance": {"type": "rgb", "value": np.pi}},
        "body": body,
    }


def per_facet_parameters(albedo, minnaert_k, n_faces: int):
    """``None`` when ``albedo`` and ``minnaert_k`` are both scalars; else both as (F,) float64 arrays.

    Each may be a scalar or an array of one value per facet; a scalar beside
    an array is repeated over the facets.
    """
    values = {"albedo": np.asarray(albedo, dtype=np.float64), "minnaert_k": np.asarray(minnaert_k, dtype=np.float64)}
    if all(value.ndim == 0 for value in values.values()):
        return None
    for name, value in values.items():
        if value.ndim != 0 and value.shape != (n_faces,):
            raise ValueError(f"{name} must be a scalar or one value per facet, shape ({n_faces},); got shape {value.shape}")
        if not np.all(np.isfinite(value)) or np.any(value < 0) or (name == "minnaert_k" and np.any(value <= 0)):
            raise ValueError(f"{name} must be finite and positive (albedo may be 0) on every facet")
    return tuple(np.broadcast_to(values[name], (n_faces,)).copy() for name in ("albedo", "minnaert_k"))


def minnaert_mesh(n_vertices: int, n_faces: int, albedo, minnaert_k):
    """An empty Mitsuba mesh with the Minnaert BSDF and flat facet normals (no vertex normals).

    ``albedo`` and ``minnaert_k`` are scalars, or one value per facet
    (``per_facet_parameters``): then they are stored as the mesh's face
    attributes and the BSDF reads them there.
    """
    import mitsuba as mi

    per_facet = per_facet_parameters(albedo, minnaert_k, n_faces)
    props = mi.Properties()
    if per_facet is None:
        props["bsdf"] = mi.load_dict({"type": "minnaert", "albedo": float(albedo), "minnaert_k": float(minnaert_k)})
    else:
        props["bsdf"] = mi.load_dict({"type": "minnaert", "per_facet": True})
    mesh = mi.Mesh("body", n_vertices, n_faces, props=props, has_vertex_normals=False)
    if per_facet is not None:
        for attribute, values in zip((ALBEDO_ATTRIBUTE, MINNAERT_K_ATTRIBUTE), per_facet):
            mesh.add_attribute(attribute, 1, mi.Float(values.astype(np.float32)))
    return mesh


def _parameter_metadata(name: str, value) -> dict:
    """frames.json entries of one parameter: its value, or ``"per_facet"`` with summary statistics."""
    value = np.asarray(value, dtype=np.float64)
    if value.ndim == 0:
        return {name: float(value)}
    return {
        name: "per_facet",
        f"{name}_mean": float(value.mean()),
        f"{name}_std": float(value.std()),
        f"{name}_min": float(value.min()),
        f"{name}_max": float(value.max()),
    }


def render_image_set(
    vertices_m: np.ndarray,
    faces: np.ndarray,
    geometry: ImagingGeometry,
    albedo,
    minnaert_k,
    light_dir_cam: np.ndarray,
    spp: int,
    out_dir: Path,
    seed: int = 0,
    variant: str = "auto",
    facet_maps_path: Path | None = None,
    bsdf: dict | None = None,
    parent_facet: np.ndarray | None = None,
    pixel_sampling: str = "area",
) -> dict:
    """Render every image of one set as a linear float EXR into ``out_dir``; write ``frames.json``.

    ``albedo`` and ``minnaert_k`` are each a scalar (uniform surface) or an
    array with one value per facet of ``faces`` (``surface_maps.facet_maps``).
    Returns the metadata written to ``frames.json``: per image the file,
    the body-to-camera pose and the true light direction in the camera frame;
    a per-facet parameter is recorded as ``"per_facet"`` with its mean, std,
    min and max. With ``facet_maps_path`` the per-facet truth (scalars
    repeated) is also written there as an .npz (``surface_maps.save_facet_maps``)
    and ``frames.json`` names it under ``facet_maps`` (relative to ``out_dir``
    when inside it).

    ``bsdf`` (a ``render_models.bsdf_dict``) renders a uniform surface of
    another photometric law instead; ``albedo`` and ``minnaert_k`` are then
    ignored and ``frames.json`` records the BSDF under ``bsdf``.

    ``parent_facet`` renders a finer mesh made from a shape model
    (``relief.relief_mesh``): ``vertices_m`` and ``faces`` are the fine
    mesh's, ``parent_facet[i]`` the shape-model facet of fine face ``i``
    (every facet ``0 .. parent_facet.max()`` has children). A per-facet
    ``albedo`` or ``minnaert_k`` then has one value per shape-model facet,
    each fine face takes its parent's, and the facet maps and the
    statistics in ``frames.json`` stay on the shape model's facets;
    ``frames.json`` gives the rendered mesh's size under ``render_mesh``.
    ``pixel_sampling``: ``area`` (``spp`` random rays per pixel) or
    ``centre`` (one ray through each pixel's centre; ``spp`` must be 1).
    """
    import mitsuba as mi

    n_facets = len(faces)
    if parent_facet is not None:
        parent_facet = np.asarray(parent_facet)
        if parent_facet.shape != (len(faces),) or not np.issubdtype(parent_facet.dtype, np.integer) or (len(faces) and parent_facet.min() < 0):
            raise ValueError(f"parent_facet must hold one non-negative facet index per face, shape ({len(faces)},); got {parent_facet.dtype} {parent_facet.shape}")
        n_facets = int(parent_facet.max()) + 1 if len(faces) else 0
    if bsdf is not None:
        albedo = minnaert_k = float("nan")
        per_facet = None
    else:
        per_facet = per_facet_parameters(albedo, minnaert_k, n_facets)  # validate before the slow set-up
    _sampler(spp, pixel_sampling)
    variant = setup_mitsuba(variant)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if bsdf is not None:
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(bsdf)
        mesh = mi.Mesh("body", len(vertices_m), len(faces), props=props, has_vertex_normals=False)
    elif per_facet is not None and parent_facet is not None:
        mesh = minnaert_mesh(len(vertices_m), len(faces), per_facet[0][parent_facet], per_facet[1][parent_facet])
    else:
        mesh = minnaert_mesh(len(vertices_m), len(faces), albedo, minnaert_k)
    mesh_params = mi.traverse(mesh)
    mesh_params["faces"] = mi.UInt32(np.ascontiguousarray(faces, dtype=np.uint32).ravel())
    mesh_params["vertex_positions"] = mi.Float(np.zeros(3 * len(vertices_m), dtype=np.float32))
    mesh_params.update()
    scene = mi.load_dict(scene_dict(geometry, light_dir_cam, spp, mesh, pixel_sampling))
    params = mi.traverse(scene)

    images = []
    started = time.perf_counter()
    for index, pose in enumerate(geometry.body_to_camera):
        vertices_world = vertices_m @ pose[:3, :3].T  # camera-aligned, centred on the body
        params["body.vertex_positions"] = mi.Float(vertices_world.astype(np.float32).ravel())
        params.update()
        image = mi.render(scene, seed=(seed * 1009 + index) % 2**32, spp=int(spp))
        name = f"image_{index:03d}.exr"
        mi.Bitmap(image).write(str(out_dir / name))
        images.append({"index": index, "file": name, "body_to_camera": pose.tolist()})
    seconds = time.perf_counter() - started
    log.info(
        "rendered %d images of %dx%d at %d spp in %.1f s (%s, %s albedo and k)", len(images), geometry.intrinsics.width,
        geometry.intrinsics.height, spp, seconds, variant, bsdf["model"] if bsdf else ("uniform" if per_facet is None else "per-facet"),
    )

    metadata = {
        **({"bsdf": bsdf} if bsdf is not None else {**_parameter_metadata("albedo", albedo), **_parameter_metadata("minnaert_k", minnaert_k)}),
        "light_dir_cam": np.asarray(light_dir_cam, float).tolist(),
        "intrinsics": geometry.intrinsics.to_dict(),
        "samples_per_pixel": int(spp),
        "pixel_sampling": pixel_sampling,
        "mitsuba_variant": variant,
        "render_seconds": seconds,
        "images": images,
    }
    if parent_facet is not None:
        metadata["render_mesh"] = {"vertices": len(vertices_m), "faces": len(faces), "shape_model_facets": n_facets}
    if facet_maps_path is not None and bsdf is None:
        from asteroid_photometry.world import surface_maps

        facet_maps_path = Path(facet_maps_path)
        albedo_map, k_map = per_facet or (np.full(n_facets, float(albedo)), np.full(n_facets, float(minnaert_k)))
        surface_maps.save_facet_maps(facet_maps_path, albedo_map, k_map)
        try:
            metadata["facet_maps"] = str(facet_maps_path.resolve().relative_to(out_dir.resolve()))
        except ValueError:
            metadata["facet_maps"] = str(facet_maps_path)
    files.write_json(out_dir / "frames.json", metadata)  # last: a set without it is incomplete
    return metadata


def read_image(path: Path) -> np.ndarray:
    """A linear single-channel float image as a (height, width) float64 array."""
    import mitsuba as mi

    if not mi.variant():
        mi.set_variant("scalar_rgb")
    try:
        bitmap = mi.Bitmap(str(path))
    except Exception as error:  # Mitsuba raises plain RuntimeErrors
        from asteroid_photometry.core.failures import BadInput

        raise BadInput(f"cannot read image {path}: {error}; expected a linear float EXR") from error
    array = np.array(bitmap, dtype=np.float64)
    return array[..., 0] if array.ndim == 3 else array


def render_sphere(radius_m: float, distance_m: float, image_size: int, fov_deg: float, albedo: float, minnaert_k: float, light_dir_cam: np.ndarray, spp: int) -> np.ndarray:
    """Render a Minnaert sphere centred on the optical axis (for the analytic check)."""
    import mitsuba as mi
    from asteroid_photometry.world.cameras import ImagingGeometry, Intrinsics

    focal_px = 0.5 * image_size / np.tan(np.radians(fov_deg) / 2)
    pose = np.eye(4)
    pose[2, 3] = distance_m
    geometry = ImagingGeometry(Intrinsics(image_size, image_size, focal_px, image_size / 2, image_size / 2), pose[None], distance_m, 0.0)
    body = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": radius_m, "bsdf": {"type": "minnaert", "albedo": albedo, "minnaert_k": minnaert_k}}
    scene = mi.load_dict(scene_dict(geometry, light_dir_cam, spp, body))
    return np.array(mi.render(scene, spp=spp), dtype=np.float64)[..., 0]
