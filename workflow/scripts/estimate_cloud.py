"""Rule script: an estimator on the reconstructed cloud, before and after photometric refinement, from the mission set alone."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import CloudStageInputs, estimate_cloud_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
estimate_cloud_stage(
    CloudStageInputs(
        registration_npz=snakemake.input.registration,  # noqa: F821
        registration_json=snakemake.input.registration_summary,  # noqa: F821
        reconstruction_dir=snakemake.input.model,  # noqa: F821
        mission_dir=snakemake.input.mission,  # noqa: F821
        refined_npz=snakemake.input.refined,  # noqa: F821
    ),
    method=snakemake.wildcards.method,  # noqa: F821
    settings=snakemake.params.settings,  # noqa: F821
    out_npz=snakemake.output.estimates,  # noqa: F821
)
