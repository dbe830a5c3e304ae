"""Rule script: sparse pycolmap reconstruction of one set from its matched features, with or without position priors."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import reconstruct_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
reconstruct_stage(snakemake.input.mission, snakemake.input.features, snakemake.output.model, snakemake.params.use_priors, snakemake.params.settings)  # noqa: F821
