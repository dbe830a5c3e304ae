"""Rule script: the candidate observations of the imaging geometry (pure pixels, no light needed)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_observation_geometry

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_observation_geometry(
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.params.observations,  # noqa: F821
    snakemake.output.npz,  # noqa: F821
)
