"""Rule script: sample each observation's brightness from the rendered images of one set."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_observations

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_observations(snakemake.input.geometry, snakemake.input.images, snakemake.output.npz)  # noqa: F821
