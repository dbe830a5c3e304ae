"""Rule script: run one estimator on one set and summarise its errors."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import fit_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
fit_set(
    snakemake.input.observations,  # noqa: F821
    snakemake.params.image_set,  # noqa: F821
    snakemake.wildcards.method,  # noqa: F821
    snakemake.output.estimates,  # noqa: F821
    snakemake.output.summary,  # noqa: F821
    set_id=snakemake.wildcards.set_id,  # noqa: F821
)
