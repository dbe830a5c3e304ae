"""Rule script: the table of one sweep (noise levels or surface maps)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_sweep_table

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_sweep_table(snakemake.input.summaries, snakemake.params.sweep, snakemake.output.csv, snakemake.output.markdown)  # noqa: F821
