"""Rule script: the pure-pixel observations of every facet for one light angle."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_observation_geometry

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_observation_geometry(
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.params.light_angle_deg,  # noqa: F821
    snakemake.params.observations,  # noqa: F821
    snakemake.output.npz,  # noqa: F821
)
