"""Rule script: every estimator on the reconstructed cloud, before and after photometric refinement, from the mission set alone."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import CloudStageInputs, estimate_cloud_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
methods = snakemake.params.methods  # noqa: F821
estimate_cloud_stage(
    CloudStageInputs.from_rule_input(snakemake.input),  # noqa: F821
    settings=snakemake.params.settings,  # noqa: F821
    out_npz=dict(zip(methods, snakemake.output.estimates, strict=True)),  # noqa: F821
)
