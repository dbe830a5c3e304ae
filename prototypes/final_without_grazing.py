"""Prototype, not part of the workflow: Table 2's final fit with the samples seen beyond an emission angle left out.

For each row of a finished run, the paper's per-point albedo and k are fitted as rule ``estimate_cloud`` does (the
mesh fit's light held and its gains divided out where it applied, else the refinement's light), once per emission
cosine cut on top of ``table2.final_observations``' own (which since d2a85a4 leaves out the samples below
``FINAL_MIN_COS_EMISSION``, 0.34: a cut below that changes nothing; the cut was chosen with this script at
3b2f797, when it had none, docs/table2.md, section 14), each point left with at least the config's
``min_observations_per_point`` samples; scored against the truth at the refined points as rule ``score_cloud``
does (the truth read only to score: never use this inside the workflow). docs/table2.md, section 13.

    python prototypes/final_without_grazing.py RUN_DIR CONFIG IMAGING CUTS SET:PRIORS...
    python prototypes/final_without_grazing.py runs/tuning_mid config/tuning_mid.yaml amica 0,0.26,0.34 light0_albedo0.3_k0.75:on
"""
import sys
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
from asteroid_photometry.evaluation import metrics  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import read_scoring_truth, truth_at_points  # noqa: E402
from asteroid_photometry.world.image_sets import condition_rendered_set  # noqa: E402


run, config_path, imaging = sys.argv[1:4]
cuts = [float(c) for c in sys.argv[4].split(",")]
rows = sys.argv[5:]
config = yaml.safe_load(Path(config_path).read_text())
settings = table2.stage_settings(config["reconstruction"], "cloud")
condition = next(c for c in config["imaging_conditions"] if c["name"] == imaging)
res = Path(run) / "results"
for spec in rows:
    set_id, priors = spec.split(":")
    row = f"{imaging}/{set_id}/priors-{priors}"
    inputs = table2.CloudStageInputs(res / f"registration/{row}.npz", res / f"registration/{row}.json", res / f"reconstruction/{row}", res / f"mission/{imaging}/{set_id}", res / f"refined_cloud/{row}.npz")
    stage = table2.read_cloud_stage(inputs, settings, observations=False)
    scoring = read_scoring_truth(res / "shape/model.npz", res / f"truth/mission/{imaging}/{set_id}.json", res / f"truth/render/{condition_rendered_set(set_id, condition)}")
    held = table2.mesh_light_of(res / f"mesh_light/{row}.npz", len(stage.images))
    stage = table2.under_mesh_light(stage, held)
    light = stage.pure.refined_light_dir_cam
    final = table2.final_observations(stage, settings)
    truth = truth_at_points(scoring, stage.transform, stage.pure.points)
    out = [spec]
    for c in cuts:
        obs = table2.seen_within_emission(final, c, settings["min_observations_per_point"])
        after = table2.plausible_points(table2.run_estimator(obs, "koizumi_lm", light_init=light, hold_light=True))
        s = metrics.summary_row(set_id, after, truth.scoring(truth.light_dir_cam))
        ok = abs(s['albedo_err']) <= 0.01 and abs(s['k_err']) <= 0.02
        out.append(f"{c:g}: a {s['albedo_err']:+.4f} k {s['k_err']:+.4f} n {s['n_points']}{'' if ok else ' X'}")
    print(" | ".join(out), flush=True)
