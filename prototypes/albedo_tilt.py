"""Prototype, not part of the workflow: the final fit's albedo with the normals' tilt out of the camera ring taken elsewhere.

Under a ring of views in one plane and a light in that plane, tilting a normal
out of the plane by an angle e scales every cosine of its point by cos(e): the
point's albedo and that tilt trade exactly (but for the perspective of the
views), and the refinement turns the normals about the spin axis only, so the
tilt is the Poisson surface's. For each row of a finished run this redoes
the final per-point fit as rule ``estimate_cloud`` does (the mesh fit's light
held, its gains divided out), each time with every refined normal turned to
another tilt out of the ring (its direction in the ring kept):

- ``asis``: the workflow's own normals;
- ``truth``: the true facet's tilt (an oracle: how much of the error is the tilt);
- ``mesh``: the tilt of the mesh fit's fitted surface at the point (its vertex
  normals, interpolated), the fit redone as rule ``mesh_light`` does it, which
  reads no truth (cached under CACHE).

It prints each variant's mean albedo and k errors over the fitted points and
the mean absolute error of the points' tilt. The truth is read only to score
and for ``truth``. docs/table2.md, section 14; docs/amica_record.md, "The
normals' tilt out of the camera ring".

    python prototypes/albedo_tilt.py RUN_DIR CONFIG IMAGING CACHE SET:PRIORS...
    python prototypes/albedo_tilt.py runs/midk config/tuning_mid.yaml amica /tmp/tilt light0_albedo0.6_k0.95:on
"""
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from albedo_bias import final_fit, rows  # noqa: E402
from asteroid_photometry.estimation import Observations  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import truth_at_points  # noqa: E402
from asteroid_photometry.from_images import refine  # noqa: E402

VARIANTS = ("asis", "truth", "mesh")


def fitted_surface(res: Path, row: str, stage: table2.CloudStage, cache: Path):
    """The mesh fit's surface (vertices, triangles) for ``row``, fitted as rule ``mesh_light`` fits it (from the
    refinement's own cloud: ``stage``'s holds the mesh fit's light and gains already)."""
    out = cache / f"{row}.npz"
    if not out.exists():
        refined = table2.read_refined_cloud(res / f"refined_cloud/{row}.npz")
        fit = table2.fit_mesh_light_on(refined, stage.oriented, stage.recon, stage.mission, stage.images)
        out.parent.mkdir(parents=True, exist_ok=True)
        np.savez(out, vertices=fit.vertices, triangles=fit.triangles)
    with np.load(out) as data:
        return data["vertices"], data["triangles"]


def vertex_normals_at(vertices, triangles, points):
    """The surface's vertex normals interpolated at the closest point to each of ``points``."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices), o3d.utility.Vector3iVector(triangles))
    mesh.compute_vertex_normals()
    normals = np.asarray(mesh.vertex_normals)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    closest = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    face, uv = closest["primitive_ids"].numpy().astype(np.int64), closest["primitive_uvs"].numpy().astype(float)
    weights = np.column_stack([1 - uv.sum(axis=1), uv[:, 0], uv[:, 1]])
    n = sum(weights[:, [i]] * normals[triangles[face, i]] for i in range(3))
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def with_tilt(normals, source, axis):
    """``normals`` turned to ``source``'s tilt out of the plane normal to ``axis``, each keeping its direction in that plane."""
    sin_tilt = np.clip(source @ axis, -1.0, 1.0)
    in_plane = normals - (normals @ axis)[:, None] * axis
    in_plane /= np.linalg.norm(in_plane, axis=1, keepdims=True)
    return np.sqrt(1 - sin_tilt**2)[:, None] * in_plane + sin_tilt[:, None] * axis


def with_normals(stage: table2.CloudStage, normals) -> table2.CloudStage:
    """``stage`` with the refined points' normals replaced (their samples' camera-frame normals with them; samples that
    would face away from their camera dropped)."""
    pure, poses = stage.pure, stage.recon.body_to_camera()
    rotations = np.array([poses.get(i, np.eye(4))[:3, :3] for i in range(max(poses) + 1)])
    obs = pure.observations
    normal_cam = np.einsum("nij,nj->ni", rotations[pure.image_index], normals[obs.point_index])
    front = np.einsum("ij,ij->i", normal_cam, obs.view_cam) > 1e-3
    kept = Observations(obs.point_index[front], normal_cam[front], obs.view_cam[front], obs.brightness[front], obs.n_points)
    return replace(stage, pure=replace(pure, normals=normals, observations=kept, image_index=pure.image_index[front]))


def main() -> None:
    if len(sys.argv) < 6:
        raise SystemExit(__doc__)
    run, config_path, imaging, cache = Path(sys.argv[1]), sys.argv[2], sys.argv[3], Path(sys.argv[4])
    res = run / "results"
    for spec, settings, stage, held, scoring in rows(run, config_path, imaging, sys.argv[5:]):
        if not held:
            print(f"{spec}: the mesh fit's light is not held there", flush=True)
            continue
        set_id, priors = spec.split(":")
        row = f"{imaging}/{set_id}/priors-{priors}"
        truth = truth_at_points(scoring, stage.transform, stage.pure.points)
        axis = refine.spin_axis(np.array(list(stage.recon.camera_centres().values())))
        rotation = stage.transform[:3, :3] / np.cbrt(np.linalg.det(stage.transform[:3, :3]))
        true_normals = truth.normals @ rotation  # body frame to the cloud's
        mesh_normals = vertex_normals_at(*fitted_surface(res, row, stage, cache / run.resolve().name), stage.pure.points)
        sources = {"asis": None, "truth": true_normals, "mesh": mesh_normals}
        parts = []
        for variant in VARIANTS:
            normals = stage.pure.normals if sources[variant] is None else with_tilt(stage.pure.normals, sources[variant], axis)
            changed = with_normals(stage, normals)
            obs = table2.final_observations(changed, settings)
            fit = final_fit(obs, changed.pure.refined_light_dir_cam)
            fitted = np.isfinite(fit.albedo) & np.isfinite(fit.minnaert_k)
            tilt_err = np.degrees(np.abs(np.arcsin(np.clip(normals @ axis, -1, 1)) - np.arcsin(np.clip(true_normals @ axis, -1, 1))))
            parts.append(
                f"{variant}: albedo {fit.albedo[fitted].mean() - truth.albedo[fitted].mean():+.4f}, k {fit.minnaert_k[fitted].mean() - truth.minnaert_k[fitted].mean():+.4f}, "
                f"{fitted.sum()} points, tilt off {tilt_err[fitted].mean():.2f} deg"
            )
        print(f"{spec}: " + " | ".join(parts), flush=True)


if __name__ == "__main__":
    main()
