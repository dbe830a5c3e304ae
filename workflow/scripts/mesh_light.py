"""Rule script: the light of a shape from shading on the reconstructed cloud's surface, from the refinement's."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import mesh_light_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
mesh_light_stage(
    snakemake.input.registration,  # noqa: F821
    snakemake.input.model,  # noqa: F821
    snakemake.input.mission,  # noqa: F821
    snakemake.input.refined,  # noqa: F821
    snakemake.output.npz,  # noqa: F821
)
