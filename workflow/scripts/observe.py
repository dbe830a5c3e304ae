"""Rule script: one set's brightness at the candidate observations, and the selection made with the estimated light."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_observations

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_observations(
    snakemake.input.geometry,  # noqa: F821
    snakemake.input.images,  # noqa: F821
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.params.observations,  # noqa: F821
    snakemake.output.npz,  # noqa: F821
)
