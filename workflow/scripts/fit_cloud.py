"""Rule script: an estimator on the reconstructed cloud, before and after photometric refinement."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import fit_cloud_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
fit_cloud_stage(
    snakemake.input.registration,  # noqa: F821
    snakemake.input.registration_summary,  # noqa: F821
    snakemake.input.model,  # noqa: F821
    snakemake.input.images,  # noqa: F821
    snakemake.input.shape,  # noqa: F821
    snakemake.input.refined,  # noqa: F821
    snakemake.wildcards.method,  # noqa: F821
    snakemake.wildcards.set_id,  # noqa: F821
    snakemake.wildcards.priors,  # noqa: F821
    snakemake.params.settings,  # noqa: F821
    snakemake.output.summary,  # noqa: F821
    snakemake.output.errors,  # noqa: F821
)
