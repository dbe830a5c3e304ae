"""Rule script: verify the shape model and write its facet table (centroids, outward normals, areas) as .npz."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.world.shape import write_prepared_model

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_prepared_model(snakemake.input.model, snakemake.params.model_name, snakemake.output.npz)  # noqa: F821
