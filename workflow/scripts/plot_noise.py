"""Rule script: observed errors of the noisy sets against their Cramér-Rao bounds."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_noise_plot

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_noise_plot(snakemake.input.table, snakemake.output.png)  # noqa: F821
