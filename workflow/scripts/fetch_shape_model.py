"""Rule script: download the shape model named by ``shape_model`` from the PDS archive and verify it."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.world.shape import download_shape_model

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
download_shape_model(snakemake.params.model_name, snakemake.output.model)  # noqa: F821
