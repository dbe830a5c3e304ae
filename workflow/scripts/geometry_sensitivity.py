"""Rule script: one set's rows of the geometry sensitivity study (tilted normals; the true surface sampled as the cloud is)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.sensitivity import sensitivity_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
sensitivity_set(
    snakemake.input.observations,  # noqa: F821
    snakemake.input.images,  # noqa: F821
    snakemake.input.shape,  # noqa: F821
    snakemake.params.image_set,  # noqa: F821
    snakemake.params.settings,  # noqa: F821
    snakemake.params.observations,  # noqa: F821
    snakemake.params.cloud,  # noqa: F821
    snakemake.wildcards.set_id,  # noqa: F821
    snakemake.output.csv,  # noqa: F821
)
