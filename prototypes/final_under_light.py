"""Prototype, not part of the workflow: Table 2's final fit of one row redone under another light, and scored.

The workflow's final estimate (rule ``estimate_cloud``) is the paper's
per-point albedo and k fitted to the refined cloud's pure samples with the
refinement's light held. This redoes that fit with the light held at the one
in LIGHT_NPZ (``light_dir_cam``, e.g. ``prototypes/mesh_sfs.py ... out=``),
and scores it as rule ``score_cloud`` does: light direction error, mean
albedo and k errors against the truth at the refined points. It prints the
row's scores under the workflow's own light first, which must match
``table2.csv``'s ``*_final`` columns (the check that this redoes the same fit).
With ``refit`` after LIGHT_NPZ it also refits the points' normals under the
given light first: one pass of the pure-sample refinement on the images
divided by the row's gains, the light held (no light step after it).

usage (from the repository root, the venv's python):
    python prototypes/final_under_light.py RUN_DIR CONFIG IMAGING SET PRIORS LIGHT_NPZ [refit]
e.g. python prototypes/final_under_light.py runs/tuning config/tuning.yaml amica light5_albedo0.15_k1.15 on light.npz
"""

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))

from asteroid_photometry.evaluation import metrics  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.from_images import cloud as cloud_lib  # noqa: E402
from asteroid_photometry.from_images import refine  # noqa: E402
from asteroid_photometry.from_images.purity import PurityTest  # noqa: E402
from asteroid_photometry.world.noise import sensor_from_config  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import read_scoring_truth, truth_at_points  # noqa: E402
from asteroid_photometry.world.image_sets import condition_rendered_set  # noqa: E402

run, config_path, imaging, set_id, priors, light_npz = sys.argv[1:7]
config = yaml.safe_load(Path(config_path).read_text())
settings = table2.stage_settings(config["reconstruction"], "cloud")
refine_settings = table2.stage_settings(config["reconstruction"], "refine")
condition = next(c for c in config["imaging_conditions"] if c["name"] == imaging)
res = Path(run) / "results"
row = f"{imaging}/{set_id}/priors-{priors}"
inputs = table2.CloudStageInputs(
    res / f"registration/{row}.npz", res / f"registration/{row}.json", res / f"reconstruction/{row}", res / f"mission/{imaging}/{set_id}", res / f"refined_cloud/{row}.npz",
)
stage = table2.read_cloud_stage(inputs, settings, observations=False)
scoring = read_scoring_truth(res / "shape/model.npz", res / f"truth/mission/{imaging}/{set_id}.json", res / f"truth/render/{condition_rendered_set(set_id, condition)}")


def scored(stage, light, tag):
    """The final fit of ``stage`` under ``light`` held, scored against the truth at its points; returns it."""
    held = replace(stage, pure=replace(stage.pure, refined_light_dir_cam=light))
    after, _, _ = table2.estimate_after_refinement(held, "koizumi_lm", float(stage.pure.refined_minnaert_k), table2.final_observations(held, settings))
    truth = truth_at_points(scoring, stage.transform, stage.pure.points)
    scores = metrics.summary_row(set_id, after, truth.scoring(truth.light_dir_cam))
    print(f"{tag}: light {scores['light_dir_err_deg']:.3f} deg, albedo {scores['albedo_err']:+.4f}, k {scores['k_err']:+.5f} ({scores['n_points']} points)", flush=True)
    return after


own = scored(stage, stage.pure.refined_light_dir_cam, "workflow's light")
given = np.asarray(np.load(light_npz)["light_dir_cam"], float)
given /= np.linalg.norm(given)
scored(stage, given, "given light")
if len(sys.argv) > 7 and sys.argv[7] == "refit":
    poses = stage.recon.body_to_camera()
    gains = stage.pure.image_gains if stage.pure.image_gains is not None else np.ones(len(stage.images))
    images = [image / gain for image, gain in zip(stage.images, gains)]
    purity_test = PurityTest(sensor_from_config(stage.mission["sensor"])) if stage.mission.get("sensor") else refine_settings["refine_purity_tolerance"]
    axis = None if stage.pure.normals_tilt_freely else refine.turn_axis(poses, stage.oriented.points.mean(axis=0), given)[0]
    refit = refine.refine_by_pure_samples(
        cloud_lib.poisson_surface(stage.oriented), poses, stage.recon.intrinsics(), images, given,
        float(np.nanmedian(own.albedo)), float(stage.pure.refined_minnaert_k),
        n_candidates=refine_settings["refine_candidates"], max_offset_px=refine_settings["refine_max_offset_px"], offset_steps=refine_settings["refine_offset_steps"],
        purity_tolerance=purity_test, max_residual=refine_settings["refine_max_residual"],
        min_observations=refine_settings["min_observations_per_point"], min_cos_emission=refine_settings["min_cos_emission"], axis=axis,
    )
    refit = replace(refit, refined_minnaert_k=stage.pure.refined_minnaert_k, image_gains=gains, normals_tilt_freely=stage.pure.normals_tilt_freely)
    scored(replace(stage, pure=refit), given, "given light, normals refitted")
