"""Rule script: render one set of the model-mismatch experiment with the photometric plugin."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.mismatch import render_model_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
render_model_set(
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.params.law,  # noqa: F821
    dict(snakemake.params.law_params),  # noqa: F821
    snakemake.params.light_angle_deg,  # noqa: F821
    snakemake.params.mitsuba_variant,  # noqa: F821
    snakemake.output.images,  # noqa: F821
    seed=snakemake.params.seed,  # noqa: F821
    threads=snakemake.threads,  # noqa: F821
)
