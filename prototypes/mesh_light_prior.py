"""Prototype, not part of the workflow: the mesh fit's light under other settings (its priors, above all).

For each row of a finished run, the mesh fit as rule ``mesh_light`` runs it (``table2.fit_mesh_light_on``, from the
row's refinement) under each of ``VARIANTS``: ``;``-separated, each a ``,``-separated list of ``MeshLightSettings``
fields set to numbers (``default`` for none); each fit is kept in ``CACHE`` and read back on a second call. Prints the light's error, its parts out of the camera ring's plane and in it, and the fit's k
against the mean true k of the refined points. The truth is read only to score. docs/dropped.md, "The mesh fit's k
offsets held more loosely".

    python prototypes/mesh_light_prior.py RUN_DIR CONFIG IMAGING CACHE VARIANTS SET:PRIORS...
    python prototypes/mesh_light_prior.py runs/midk config/tuning_mid.yaml amica /tmp/dk \
        'default;sigma_dk=0.05;sigma_dk=0.1' light0_albedo0.3_k0.75:on
"""
import functools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from albedo_bias import rows  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import BODY_SPIN_AXIS, true_poses, truth_at_points  # noqa: E402
from asteroid_photometry.from_images import mesh_light  # noqa: E402


def main() -> None:
    if len(sys.argv) < 7:
        raise SystemExit(__doc__)
    run, config, imaging, cache = Path(sys.argv[1]), sys.argv[2], sys.argv[3], Path(sys.argv[4])
    variants = sys.argv[5].split(";")
    fit_as_workflow = mesh_light.fit_mesh_light
    for spec, _, stage, _, scoring in rows(run, config, imaging, sys.argv[6:]):
        set_id, priors = spec.split(":")
        row = f"{imaging}/{set_id}/priors-{priors}"
        refined = table2.read_refined_cloud(run / f"results/refined_cloud/{row}.npz")
        truth = truth_at_points(scoring, stage.transform, stage.pure.points)
        spin_cam = true_poses(scoring.truth)[0, :3, :3] @ BODY_SPIN_AXIS
        for variant in variants:
            out = cache / f"{variant}/{row}.npz"
            if not out.exists():
                fields = {} if variant == "default" else {key: float(value) for key, value in (item.split("=") for item in variant.split(","))}
                mesh_light.fit_mesh_light = functools.partial(fit_as_workflow, settings=mesh_light.MeshLightSettings(**fields))
                fit = table2.fit_mesh_light_on(refined, stage.oriented, stage.recon, stage.mission, stage.images)
                out.parent.mkdir(parents=True, exist_ok=True)
                np.savez(out, light_dir_cam=fit.light_dir_cam, minnaert_k=fit.minnaert_k)
            with np.load(out) as data:
                light, k = data["light_dir_cam"], float(data["minnaert_k"])
            error = np.degrees(np.arccos(np.clip(light @ truth.light_dir_cam, -1.0, 1.0)))
            elevation = np.degrees(np.arcsin(np.clip(light @ spin_cam, -1, 1)) - np.arcsin(np.clip(truth.light_dir_cam @ spin_cam, -1, 1)))
            print(f"{imaging} {spec} {variant}: light {error:.3f} deg (elevation {elevation:+.3f}, in the ring's plane {np.sqrt(max(error**2 - elevation**2, 0.0)):.3f}), k {k - float(np.mean(truth.minnaert_k)):+.4f}", flush=True)


if __name__ == "__main__":
    main()
