"""Rule script: every estimator on one set, each with its own estimates and summary of its errors."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import fit_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
outputs = zip(snakemake.params.methods, snakemake.output.estimates, snakemake.output.summaries, strict=True)  # noqa: F821
for method, estimates, summary in outputs:
    fit_set(
        snakemake.input.observations,  # noqa: F821
        snakemake.params.image_set,  # noqa: F821
        method,
        estimates,
        summary,
        set_id=snakemake.wildcards.set_id,  # noqa: F821
    )
