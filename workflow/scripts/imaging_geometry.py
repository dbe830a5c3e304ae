"""Rule script: intrinsics and per-image body-to-camera poses as JSON."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import write_imaging_geometry

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_imaging_geometry(snakemake.input.shape, snakemake.output.cameras, **snakemake.params)  # noqa: F821
