"""Rule script: the oriented cloud of a reconstruction, registered to the shape model and scored."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import register_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
register_stage(snakemake.input.model, snakemake.input.shape, snakemake.params.settings, snakemake.output.npz, snakemake.output.summary)  # noqa: F821
