"""Prototype, not part of the workflow: the mesh fit's own statistical uncertainty of its light, beside its error.

For each row of a finished run, the mesh fit as rule ``mesh_light`` runs it (``table2.fit_mesh_light_on``); from the
column-scaled normal matrix of its last step (the samples' information and the priors') the standard deviations of
the light's two angles and of the body's k (the inverse's diagonal, by the fit's own sparse LU), with the k offsets'
prior and without it (each cell's k free). Set against the
light's error, it says how much of that error the images' noise explains under the fit's model. The truth is read
only to score. docs/amica_record.md, "One map behind the paper's 16 sets".

    python prototypes/mesh_light_std.py RUN_DIR CONFIG IMAGING SET:PRIORS...
    python prototypes/mesh_light_std.py . config/config.yaml amica light0_albedo0.7_k0.9:on
"""
import sys
from pathlib import Path

import numpy as np
from scipy.sparse.linalg import splu

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflow"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from albedo_bias import rows  # noqa: E402
from asteroid_photometry.experiments import table2  # noqa: E402
from asteroid_photometry.experiments.table2_scoring import truth_at_points  # noqa: E402
from asteroid_photometry.from_images import mesh_light  # noqa: E402

last = {}
_scaled_normal, _problem = mesh_light._scaled_normal, mesh_light._MeshProblem


def keep_normal(J, prior_normal, scale):
    last["normal"], last["scale"] = _scaled_normal(J, prior_normal, scale), scale
    return last["normal"]


class KeptProblem(_problem):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        last["problem"] = self


def main() -> None:
    if len(sys.argv) < 5:
        raise SystemExit(__doc__)
    mesh_light._scaled_normal, mesh_light._MeshProblem = keep_normal, KeptProblem
    run, config, imaging = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    for spec, _, stage, _, scoring in rows(run, config, imaging, sys.argv[4:]):
        set_id, priors = spec.split(":")
        refined = table2.read_refined_cloud(run / f"results/refined_cloud/{imaging}/{set_id}/priors-{priors}.npz")
        fit = table2.fit_mesh_light_on(refined, stage.oriented, stage.recon, stage.mission, stage.images)
        problem, scale = last["problem"], last["scale"]
        truth = truth_at_points(scoring, stage.transform, stage.pure.points)
        error = np.degrees(np.arccos(np.clip(fit.light_dir_cam @ truth.light_dir_cam, -1.0, 1.0)))
        with_prior = standard_deviations(problem, last["normal"], scale)
        # The same with the k offsets' prior taken off (each cell's k free): what the samples alone say.
        free, dk = last["normal"].copy(), slice(problem.o_dk, problem.o_dk + problem.ncell)
        diagonal = free.diagonal()
        diagonal[dk] -= (scale[dk] / problem.settings.sigma_dk) ** 2
        free.setdiag(diagonal)
        without_prior = standard_deviations(problem, free, scale)
        print(f"{imaging} {spec}: light {error:.3f} deg off; the fit's standard deviation of the light's two angles "
              f"{np.degrees(with_prior[0]):.4f} and {np.degrees(with_prior[1]):.4f} deg, of k {with_prior[2]:.5f}; "
              f"the k offsets free: {np.degrees(without_prior[0]):.4f} and {np.degrees(without_prior[1]):.4f} deg, of k {without_prior[2]:.5f}", flush=True)


def standard_deviations(problem, normal, scale) -> list[float]:
    """The standard deviations of the light's two angles and of the body's k: the diagonal of the inverse of the
    column-scaled ``normal`` at those unknowns, by the fit's own sparse LU."""
    normal = normal.copy()
    normal.setdiag(normal.diagonal() + 1e-9)  # cells no sample reached have no information at all
    order = problem.order
    lu = splu(normal[order][:, order].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    std = []
    for column in (problem.o_l, problem.o_l + 1, problem.o_k):
        unit = np.zeros(normal.shape[0])
        unit[column] = 1.0
        solved = np.empty_like(unit)
        solved[order] = lu.solve(unit[order])
        std.append(float(np.sqrt(solved[column]) * scale[column]))
    return std


if __name__ == "__main__":
    main()
