"""Prototype, not part of the workflow: where the mesh fit's light error comes from, the truth put in one part at a time.

An offline experiment on Table 2 rows of a finished run (docs/amica_record.md, "Where the mesh fit's light error at
light 0 comes from"). For each row it runs the workflow's mesh fit (``from_images.mesh_light.fit_mesh_light``) from
the refinement's light and k, as rule ``mesh_light`` does, in these variants:

- ``base``: the cloud's Poisson surface (octree depth 7) and the reconstructed cameras (what the workflow did before
  46d0b84);
- ``workflow``: as ``base`` on the surface of depth 8 (what rule ``mesh_light`` does, since f2daff2 as
  ``workflow_psf``);
- ``truecam``: that surface moved into the body frame by the registration, seen through the true cameras;
- ``trueshape``: the shape model's own facets through the true cameras;
- ``trueshapegain``: as ``trueshape``, the images divided by the true calibration gains, the gains then held;
- ``trueshapezF``: as ``trueshape``, the shape model scaled along the spin axis by the factor F (``trueshapez0.98``);
- ``heightsR``: as ``truecam`` on the workflow's surface (octree depth 8), the vertices of region R each moved along
  its normal onto the shape model (the height the mesh fit would need there): ``all``, ``north`` or ``south`` (normal
  more than 20 degrees out of the equator's plane, towards either pole), ``band`` (within 20 degrees of it) or
  ``none``;
- any of them with ``_psf``: the model blurred by the mission's stated PSF (``table2.mesh_light_psf``, as rule
  ``mesh_light`` blurs it).

The fit runs at its default settings (since f2daff2 cells of 7 footprints, ``sigma_dk`` 0.1), or at those of the
environment variable ``MESH_LIGHT_SETTINGS`` (``MeshLightSettings`` fields, e.g. ``sigma_dk=0.025,cell_px=14``, the
defaults before f2daff2), in every variant.

It reads the truth (the mission set's truth file, the shape model) for the oracles and to print each light's error:
never use it inside the workflow.

    python prototypes/mesh_light_oracle.py RUN_DIR CONDITION VARIANTS SET:PRIORS...
    python prototypes/mesh_light_oracle.py runs/tuning_mid amica base,trueshape,trueshape_psf light0_albedo0.3_k0.75:on
"""

import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "workflow"))

from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.from_images import cloud as cloud_lib, mesh_light, register  # noqa: E402
from asteroid_photometry.from_images.purity import PurityTest  # noqa: E402
from asteroid_photometry.world.cameras import Intrinsics  # noqa: E402
from asteroid_photometry.world.noise import sensor_from_config  # noqa: E402


def angle_deg(a, b) -> float:
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


def heights_onto(vertices, triangles, shape: dict, region: str, edge: float):
    """``vertices``/``triangles`` subdivided to edges of about ``edge`` (as the mesh fit would subdivide them), then the
    vertices of ``region`` (see the module's docstring) moved along their normals onto the shape model's surface, to the
    nearest crossing within 30 m either way; the others, and those with no crossing, left where they are."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    while np.median(np.linalg.norm(vertices[triangles[:, 0]] - vertices[triangles[:, 1]], axis=1)) > edge:
        mesh = mesh.subdivide_midpoint(number_of_iterations=1)
        vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    normals = np.asarray(mesh.compute_vertex_normals().vertex_normals)
    up, tilted = normals[:, 2], np.sin(np.radians(20))
    regions = {"all": np.ones(len(up), bool), "north": up > tilted, "south": up < -tilted, "band": np.abs(up) <= tilted, "none": np.zeros(len(up), bool)}
    if region not in regions:
        raise SystemExit(f"unknown region {region!r} of variant heightsR: {', '.join(regions)}")
    chosen = regions[region]
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(shape["vertices_m"].astype(np.float32)), o3d.core.Tensor(shape["faces"].astype(np.uint32)))
    steps = []
    for sign in (1.0, -1.0):
        rays = np.hstack([vertices, sign * normals]).astype(np.float32)
        steps.append(sign * scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
    forward, backward = steps
    step = np.where(np.abs(forward) <= np.abs(backward), forward, backward)
    move = chosen & (np.abs(step) <= 30.0)
    print(f"  heights{region}: {move.sum()} of {len(up)} vertices moved, median |step| {np.median(np.abs(step[move])) if move.any() else 0:.2f} m", flush=True)
    out = vertices.copy()
    out[move] += step[move, None] * normals[move]
    return out, triangles


def row(run: Path, condition: str, set_id: str, priors: str, variants: list[str], shape: dict, settings: dict, fit_settings) -> str:
    results = run / "results"
    inputs = table2.CloudStageInputs(
        results / f"registration/{condition}/{set_id}/priors-{priors}.npz", results / f"registration/{condition}/{set_id}/priors-{priors}.json",
        results / f"reconstruction/{condition}/{set_id}/priors-{priors}", results / f"mission/{condition}/{set_id}",
        results / f"refined_cloud/{condition}/{set_id}/priors-{priors}.npz",
    )
    stage = table2.read_cloud_stage(inputs, settings, observations=False)
    truth = json.loads((results / f"truth/mission/{condition}/{set_id}.json").read_text())
    true_light = np.asarray(truth["light_dir_cam"], float)
    pure = stage.pure
    gains = pure.image_gains if pure.image_gains is not None else np.ones(len(stage.images))
    vertices, triangles = cloud_lib.poisson_surface(stage.oriented)
    deep = cloud_lib.poisson_surface(stage.oriented, depth=table2.MESH_LIGHT_POISSON_DEPTH)
    poses, centres = stage.recon.body_to_camera(), stage.recon.camera_centres()
    true_poses = {i: np.asarray(truth["images"][i]["body_to_camera"], float) for i in poses}
    true_centres = {i: -pose[:3, :3].T @ pose[:3, 3] for i, pose in true_poses.items()}
    variance = PurityTest(sensor_from_config(stage.mission["sensor"])).sample_variance
    cells = [f"start {angle_deg(pure.refined_light_dir_cam, true_light):.3f}"]
    for variant in variants:
        name, psf = variant.removesuffix("_psf"), table2.mesh_light_psf(stage.mission) if variant.endswith("_psf") else None
        images, gain_sigma = [image / gain for image, gain in zip(stage.images, gains)], float(stage.mission.get("gain_sigma") or 0.0)
        if name == "base":
            geometry = (vertices, triangles, centres, poses, stage.recon.intrinsics())
        elif name == "workflow":
            geometry = (*deep, centres, poses, stage.recon.intrinsics())
        elif name == "truecam":
            geometry = (register.transform_points(stage.transform, vertices), triangles, true_centres, true_poses, Intrinsics(**stage.mission["intrinsics"]))
        elif name in ("trueshape", "trueshapegain") or name.startswith("trueshapez"):
            # trueshapezF: squashed or stretched along the spin axis (about the body's origin) by the factor F.
            along_spin = float(name.removeprefix("trueshapez")) if name.startswith("trueshapez") else 1.0
            geometry = (shape["vertices_m"] * np.array([1.0, 1.0, along_spin]), shape["faces"], true_centres, true_poses, Intrinsics(**stage.mission["intrinsics"]))
            if name == "trueshapegain":
                images, gain_sigma = [image / gain for image, gain in zip(stage.images, truth["gains"])], 0.0
        elif name.startswith("heights"):
            intrinsics = Intrinsics(**stage.mission["intrinsics"])
            edge = fit_settings.edge_px * float(np.median([np.linalg.norm(c) for c in true_centres.values()])) / intrinsics.focal_px
            moved = heights_onto(register.transform_points(stage.transform, deep[0]), deep[1], shape, name.removeprefix("heights"), edge)
            geometry = (*moved, true_centres, true_poses, intrinsics)
        else:
            raise SystemExit(f"unknown variant {variant!r}: base, workflow, truecam, trueshape, trueshapegain, trueshapezF, heightsR, each optionally with _psf")
        tick = time.perf_counter()
        fit = mesh_light.fit_mesh_light(*geometry, images, variance, pure.refined_light_dir_cam, pure.refined_minnaert_k, gain_sigma, psf=psf, settings=fit_settings)
        cells.append(f"{variant} {angle_deg(fit.light_dir_cam, true_light):.3f} (y {fit.light_dir_cam[1]:+.4f}) k {fit.minnaert_k:.3f} {time.perf_counter() - tick:.0f}s")
    return f"{set_id}:{priors} " + " | ".join(cells)


def main() -> None:
    if len(sys.argv) < 5:
        raise SystemExit(__doc__)
    logging.disable(logging.WARNING)
    run, condition, variants = Path(sys.argv[1]), sys.argv[2], sys.argv[3].split(",")
    # MESH_LIGHT_SETTINGS="sigma_dk=0.1,cell_px=7": the fit's settings (MeshLightSettings fields) for every variant.
    spec = os.environ.get("MESH_LIGHT_SETTINGS", "")
    fit_settings = mesh_light.MeshLightSettings(**{key: float(value) for key, value in (item.split("=") for item in spec.split(",") if item)})
    config = yaml.safe_load(Path("config/config.yaml").read_text())
    settings = table2.stage_settings(config["reconstruction"], "cloud")
    with np.load(run / "results/shape/model.npz") as data:
        shape = {key: data[key] for key in ("vertices_m", "faces")}
    for spec in sys.argv[4:]:
        set_id, priors = spec.split(":")
        print(row(run, condition, set_id, priors, variants, shape, settings, fit_settings), flush=True)


if __name__ == "__main__":
    main()
