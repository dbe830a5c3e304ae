"""Rule script: the 8-bit images, SIFT features and verified matches of one mission set."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import match_features_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
match_features_stage(snakemake.input.mission, snakemake.output.features, snakemake.threads, snakemake.params.settings)  # noqa: F821
