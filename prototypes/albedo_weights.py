"""Prototype, not part of the workflow: the body's albedo and k from the well-seen points only.

For each row of a finished run, the final per-point fit as in ``albedo_bias.py`` (rule ``estimate_cloud``'s), then
the body's albedo and k errors as a weighted mean over the fitted points, the truth weighted the same way:

- ``weights``: each point weighed by 1 / (e + |g|^2), ``g`` the change of its log albedo with a tilt of its normal
  (from its own samples under the held light and its fitted k, turned into the cloud's frame; no truth), for e in
  ``--eps``;
- ``cut``: the points of mean emission cosine at least c kept, for c in ``--cuts``.

The truth is read only to score. docs/dropped.md, "The body's albedo from the well-seen points only".

    python prototypes/albedo_weights.py RUN_DIR CONFIG IMAGING SET:PRIORS...
    python prototypes/albedo_weights.py runs/tuning-72 config/tuning.yaml amica light5_albedo0.85_k1.15:on
"""
import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from albedo_bias import final_fit, rows  # noqa: E402
from asteroid_photometry.estimation import Observations  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import truth_at_points  # noqa: E402


def final_image_index(stage, settings) -> np.ndarray:
    """The image of each of ``table2.final_observations``' rows (its filters do not read the brightness, which here
    carries the image index through them)."""
    pure = stage.pure
    obs = pure.observations
    tagged = Observations(obs.point_index, obs.normal_cam, obs.view_cam, pure.image_index + 1.0, obs.n_points)
    return np.rint(table2.final_observations(replace(stage, pure=replace(pure, observations=tagged)), settings).brightness).astype(int) - 1


def tilt_sensitivity(obs, image, normals, light, k_point) -> np.ndarray:
    """Per point, |g|^2: g the mean over its samples of d log(brightness) / d(normal), in the cloud's frame."""
    n, ci, ce = obs.normal_cam, obs.normal_cam @ light, obs.cos_emission
    k = k_point[obs.point_index][:, None]
    d = k * (light[None, :] - ci[:, None] * n) / ci[:, None] + (k - 1) * (obs.view_cam - ce[:, None] * n) / ce[:, None]
    cloud = np.zeros_like(d)
    for j in np.unique(image):
        rows_j = image == j
        to_camera, _ = Rotation.align_vectors(n[rows_j], normals[obs.point_index[rows_j]])
        cloud[rows_j] = to_camera.inv().apply(d[rows_j])
    g = obs.point_means(cloud)
    return np.sum(g * g, axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("config")
    parser.add_argument("imaging")
    parser.add_argument("rows", nargs="+")
    parser.add_argument("--eps", type=float, nargs="*", default=[0.003, 0.01, 0.03, 0.1])
    parser.add_argument("--cuts", type=float, nargs="*", default=[0.5, 0.6, 0.7])
    args = parser.parse_args()
    for spec, settings, stage, _, scoring in rows(args.run, args.config, args.imaging, args.rows):
        light = stage.pure.refined_light_dir_cam
        obs = table2.final_observations(stage, settings)
        fit = final_fit(obs, light)
        truth = truth_at_points(scoring, stage.transform, stage.pure.points)
        ok = np.isfinite(fit.albedo) & np.isfinite(fit.minnaert_k)
        albedo_err = (fit.albedo - np.broadcast_to(truth.albedo, fit.albedo.shape))[ok]
        k_err = (fit.minnaert_k - np.broadcast_to(truth.minnaert_k, fit.albedo.shape))[ok]
        s2 = tilt_sensitivity(obs, final_image_index(stage, settings), stage.pure.normals, light, np.nan_to_num(fit.minnaert_k, nan=1.0))[ok]
        mean_cos_e = obs.point_means(obs.cos_emission)[ok]
        variants = [("mean", np.ones(ok.sum()))]
        variants += [(f"weights e={e:g}", 1.0 / (e + s2)) for e in args.eps]
        variants += [(f"cut {c:g}", (mean_cos_e >= c).astype(float)) for c in args.cuts]
        print(f"{args.imaging} {spec}: {ok.sum()} points", flush=True)
        for name, w in variants:
            print(f"  {name:16s} albedo {np.sum(w * albedo_err) / w.sum():+.4f} k {np.sum(w * k_err) / w.sum():+.4f} "
                  f"(effective points {w.sum() ** 2 / np.sum(w * w):.0f})", flush=True)


if __name__ == "__main__":
    main()
