"""Rule script: one noise level drawn many times on one clean set, each draw fitted and scored against the bound."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.monte_carlo import noise_monte_carlo_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
noise_monte_carlo_set(
    snakemake.input.geometry,  # noqa: F821
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.params.observations,  # noqa: F821
    snakemake.input.images,  # noqa: F821
    snakemake.params.sensor,  # noqa: F821
    snakemake.params.seed,  # noqa: F821
    snakemake.params.realisations,  # noqa: F821
    snakemake.params.image_set,  # noqa: F821
    snakemake.wildcards.set_id,  # noqa: F821
    snakemake.output.csv,  # noqa: F821
)
