"""Rule script: the estimates on one reconstructed cloud scored against the truth (its rows of Table 2, one per estimator)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2 import CloudStageInputs
from asteroid_photometry.experiments.table2_scoring import score_cloud_stage, ScoringInputs

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
methods = snakemake.params.methods  # noqa: F821
score_cloud_stage(
    CloudStageInputs.from_rule_input(snakemake.input),  # noqa: F821
    ScoringInputs.from_rule_input(snakemake.input, methods),  # noqa: F821
    set_id=snakemake.wildcards.set_id,  # noqa: F821
    imaging=snakemake.wildcards.imaging,  # noqa: F821
    priors=snakemake.wildcards.priors,  # noqa: F821
    settings=snakemake.params.settings,  # noqa: F821
    out_json=dict(zip(methods, snakemake.output.summary, strict=True)),  # noqa: F821
    out_npz=dict(zip(methods, snakemake.output.errors, strict=True)),  # noqa: F821
)
