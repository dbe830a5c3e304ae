"""Rule script: Table 2's figures (errors from cloud to truth; one cloud coloured by its errors)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2_scoring import write_table2_plots

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_table2_plots(
    snakemake.input.table,  # noqa: F821
    snakemake.input.cloud_errors,  # noqa: F821
    snakemake.params.method,  # noqa: F821
    snakemake.params.title,  # noqa: F821
    snakemake.output.stages,  # noqa: F821
    snakemake.output.cloud,  # noqa: F821
    snakemake.output.conditions,  # noqa: F821
)
