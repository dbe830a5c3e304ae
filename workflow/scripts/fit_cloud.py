"""Rule script: an estimator on the reconstructed cloud, before and after photometric refinement."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import CloudStageInputs, fit_cloud_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
fit_cloud_stage(
    CloudStageInputs(
        registration_npz=snakemake.input.registration,  # noqa: F821
        registration_json=snakemake.input.registration_summary,  # noqa: F821
        reconstruction_dir=snakemake.input.model,  # noqa: F821
        render_dir=snakemake.input.images,  # noqa: F821
        shape_npz=snakemake.input.shape,  # noqa: F821
        refined_npz=snakemake.input.refined,  # noqa: F821
    ),
    method=snakemake.wildcards.method,  # noqa: F821
    set_id=snakemake.wildcards.set_id,  # noqa: F821
    priors=snakemake.wildcards.priors,  # noqa: F821
    settings=snakemake.params.settings,  # noqa: F821
    out_json=snakemake.output.summary,  # noqa: F821
    out_npz=snakemake.output.errors,  # noqa: F821
)
