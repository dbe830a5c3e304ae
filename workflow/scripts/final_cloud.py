"""Rule script: the refined cloud the final fit reads (on noise-free images under the mesh fit's light, its normals refitted)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import final_cloud_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
final_cloud_stage(
    snakemake.input.registration,  # noqa: F821
    snakemake.input.model,  # noqa: F821
    snakemake.input.mission,  # noqa: F821
    snakemake.input.refined,  # noqa: F821
    snakemake.input.mesh_light,  # noqa: F821
    snakemake.params.settings,  # noqa: F821
    snakemake.output.npz,  # noqa: F821
)
