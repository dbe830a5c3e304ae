"""Rule script: the model-mismatch table, its markdown and plots."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.mismatch import write_tables

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_tables(
    snakemake.input.rows,  # noqa: F821
    snakemake.output.csv,  # noqa: F821
    snakemake.output.markdown,  # noqa: F821
    snakemake.output.phase,  # noqa: F821
    snakemake.output.residuals,  # noqa: F821
)
