"""Rule script: plots of our errors beside the paper's, and per-point error distributions."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_table1_plots

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_table1_plots(snakemake.input.table, snakemake.input.estimates, snakemake.output)  # noqa: F821
