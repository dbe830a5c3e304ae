"""Rule script: a rendered set as a mission would know it (images under an imaging condition, navigation), and its truth apart."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.mission import mission_stage

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
mission_stage(
    snakemake.input.images,  # noqa: F821
    snakemake.params.condition,  # noqa: F821
    snakemake.params.noise_levels,  # noqa: F821
    snakemake.params.seed,  # noqa: F821
    snakemake.params.prior_seed,  # noqa: F821
    snakemake.output.mission,  # noqa: F821
    snakemake.output.truth,  # noqa: F821
)
