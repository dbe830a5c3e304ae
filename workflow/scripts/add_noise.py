"""Rule script: a clean set's images as a noisy sensor records them."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import add_noise_to_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
add_noise_to_set(snakemake.input.images, snakemake.params.sensor, snakemake.params.seed, snakemake.output.images)  # noqa: F821
