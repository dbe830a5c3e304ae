"""Rule script: the benchmarks of every heavy job, and the fits' own timings, tabulated."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_runtime_table

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_runtime_table(snakemake.input.benchmarks, snakemake.input.summaries, snakemake.output.csv, snakemake.output.fit_timing)  # noqa: F821
