"""Rule script: a reconstructed cloud's samples moved to where the images show them pure, with normals fitted to them."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import refine_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
refine_stage(
    snakemake.input.registration,  # noqa: F821
    snakemake.input.model,  # noqa: F821
    snakemake.input.mission,  # noqa: F821
    snakemake.params.settings,  # noqa: F821
    snakemake.output.npz,  # noqa: F821
)
