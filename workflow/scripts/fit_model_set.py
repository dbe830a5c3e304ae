"""Rule script: identity fit, cross-fits and Fisher rows of one set of the model-mismatch experiment."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.mismatch import fit_model_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
fit_model_set(
    snakemake.input.geometry,  # noqa: F821
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.input.images,  # noqa: F821
    snakemake.params.law,  # noqa: F821
    snakemake.params.light_angle_deg,  # noqa: F821
    snakemake.params.observations,  # noqa: F821
    snakemake.params.settings,  # noqa: F821
    snakemake.params.sensor,  # noqa: F821
    snakemake.params.seed,  # noqa: F821
    snakemake.output.json,  # noqa: F821
)
