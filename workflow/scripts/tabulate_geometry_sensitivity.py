"""Rule script: the geometry sensitivity rows of all sets as one table, its summary and its plot."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.sensitivity import write_table

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_table(snakemake.input.rows, snakemake.output.csv, snakemake.output.markdown, snakemake.output.png)  # noqa: F821
