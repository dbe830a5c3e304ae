"""Rule script: per-point errors of a spatially varying surface, drawn on the body."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_error_map_plot

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_error_map_plot(snakemake.input.shape, snakemake.input.estimates, snakemake.params.title, snakemake.output.png)  # noqa: F821
