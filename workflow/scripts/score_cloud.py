"""Rule script: the estimates on one reconstructed cloud scored against the truth (a row of Table 2)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import CloudStageInputs, score_cloud_stage, ScoringInputs

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
score_cloud_stage(
    CloudStageInputs(
        registration_npz=snakemake.input.registration,  # noqa: F821
        registration_json=snakemake.input.registration_summary,  # noqa: F821
        reconstruction_dir=snakemake.input.model,  # noqa: F821
        mission_dir=snakemake.input.mission,  # noqa: F821
        refined_npz=snakemake.input.refined,  # noqa: F821
    ),
    ScoringInputs(
        estimates_npz=snakemake.input.estimates,  # noqa: F821
        shape_npz=snakemake.input.shape,  # noqa: F821
        truth_json=snakemake.input.truth,  # noqa: F821
        render_dir=snakemake.input.render_truth,  # noqa: F821
    ),
    method=snakemake.wildcards.method,  # noqa: F821
    set_id=snakemake.wildcards.set_id,  # noqa: F821
    imaging=snakemake.wildcards.imaging,  # noqa: F821
    priors=snakemake.wildcards.priors,  # noqa: F821
    settings=snakemake.params.settings,  # noqa: F821
    out_json=snakemake.output.summary,  # noqa: F821
    out_npz=snakemake.output.errors,  # noqa: F821
)
