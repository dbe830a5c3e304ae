"""Rule script: the noise Monte Carlo's per-set summary against the Cramer-Rao bound."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.monte_carlo import write_monte_carlo_table

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_monte_carlo_table(snakemake.input.draws, snakemake.output.csv, snakemake.output.markdown)  # noqa: F821
