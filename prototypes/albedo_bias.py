"""Prototype, not part of the workflow: where the final fit's albedo error comes from, by how obliquely each point is seen.

For each row of a finished run, the paper's per-point albedo and k are fitted as rule ``estimate_cloud`` does (the mesh
fit's light held and its gains divided out where it applied, else the refinement's light, on
``table2.final_observations``). It prints the mean albedo and k errors over the fitted points, then by the points'
mean emission cosine over their samples, and the estimator's own bias under the sensor's noise: the fitted model's
brightness redrawn with the mission's stated noise (``PurityTest.sample_variance``) and fitted again, ``DRAWS``
times, which reads no truth. The truth is read only to score (never use this inside the workflow). docs/table2.md,
section 14.

    python prototypes/albedo_bias.py RUN_DIR CONFIG IMAGING DRAWS SET:PRIORS...
    python prototypes/albedo_bias.py . config/config.yaml amica 2 light0_albedo0.7_k1:on
"""
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
from asteroid_photometry.estimation import Observations  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import read_scoring_truth, truth_at_points  # noqa: E402
from asteroid_photometry.from_images.purity import PurityTest  # noqa: E402
from asteroid_photometry.world.image_sets import condition_rendered_set  # noqa: E402
from asteroid_photometry.world.noise import sensor_from_config  # noqa: E402

BINS = ((0.0, 0.5), (0.5, 0.7), (0.7, 0.85), (0.85, 1.01))


def final_fit(observations, light):
    return table2.plausible_points(table2.run_estimator(observations, "koizumi_lm", light_init=light, hold_light=True))


def rows(run: Path, config_path: str, imaging: str, specs):
    """For each ``SET:PRIORS`` of ``specs``: (spec, settings, the row's stage under the mesh fit's light and gains where
    they are held, whether they are, the scoring truth). The stage is read as rule ``estimate_cloud`` reads it."""
    config = yaml.safe_load(Path(config_path).read_text())
    settings = table2.stage_settings(config["reconstruction"], "cloud")
    condition = next(c for c in config["imaging_conditions"] if c["name"] == imaging)
    res = run / "results"
    for spec in specs:
        set_id, priors = spec.split(":")
        row = f"{imaging}/{set_id}/priors-{priors}"
        inputs = table2.CloudStageInputs(
            res / f"registration/{row}.npz", res / f"registration/{row}.json", res / f"reconstruction/{row}", res / f"mission/{imaging}/{set_id}", res / f"refined_cloud/{row}.npz"
        )
        stage = table2.read_cloud_stage(inputs, settings, observations=False)
        held = table2.mesh_light_of(res / f"mesh_light/{row}.npz", len(stage.images))
        scoring = read_scoring_truth(res / "shape/model.npz", res / f"truth/mission/{imaging}/{set_id}.json", res / f"truth/render/{condition_rendered_set(set_id, condition)}")
        yield spec, settings, table2.under_mesh_light(stage, held), held is not None, scoring


def main() -> None:
    if len(sys.argv) < 6:
        raise SystemExit(__doc__)
    run, config_path, imaging, draws = Path(sys.argv[1]), sys.argv[2], sys.argv[3], int(sys.argv[4])
    rng = np.random.default_rng(1)
    for spec, settings, stage, _, scoring in rows(run, config_path, imaging, sys.argv[5:]):
        light = stage.pure.refined_light_dir_cam
        obs = table2.final_observations(stage, settings)
        fit = final_fit(obs, light)
        truth = truth_at_points(scoring, stage.transform, stage.pure.points)
        fitted = np.isfinite(fit.albedo) & np.isfinite(fit.minnaert_k)
        albedo_err, k_err = fit.albedo - truth.albedo, fit.minnaert_k - truth.minnaert_k
        mean_cos_e = obs.point_means(obs.cos_emission)
        print(f"{spec}: {fitted.sum()} points, albedo {albedo_err[fitted].mean():+.4f} (median {np.median(albedo_err[fitted]):+.4f}), k {k_err[fitted].mean():+.4f}", flush=True)
        for low, high in BINS:
            chosen = fitted & (mean_cos_e >= low) & (mean_cos_e < high)
            if chosen.any():
                print(f"  mean emission cosine [{low}, {high}): {chosen.sum():6d} points, albedo {albedo_err[chosen].mean():+.4f}, k {k_err[chosen].mean():+.4f}", flush=True)
        albedo, k = np.nan_to_num(fit.albedo[obs.point_index]), np.nan_to_num(fit.minnaert_k[obs.point_index], nan=1.0)
        model = albedo * np.clip(obs.cos_incidence(light), 1e-6, None) ** k * obs.cos_emission ** (k - 1)
        variance = PurityTest(sensor_from_config(stage.mission["sensor"])).sample_variance(np.maximum(model, 1e-9))
        for draw in range(draws):
            drawn = Observations(obs.point_index, obs.normal_cam, obs.view_cam, np.maximum(model + rng.normal(0.0, np.sqrt(variance)), 1e-9), obs.n_points)
            again = final_fit(drawn, light)
            both = fitted & np.isfinite(again.albedo) & np.isfinite(again.minnaert_k)
            print(f"  noise draw {draw}: albedo bias {again.albedo[both].mean() - fit.albedo[both].mean():+.5f}, k bias {again.minnaert_k[both].mean() - fit.minnaert_k[both].mean():+.5f}", flush=True)


if __name__ == "__main__":
    main()
