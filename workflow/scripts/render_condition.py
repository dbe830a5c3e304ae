"""Rule script: an imaging condition's own render of one set (its cameras, its Sun out of the camera's x-z plane, its relief)."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table1 import render_set

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
render_set(
    snakemake.input.shape,  # noqa: F821
    snakemake.input.cameras,  # noqa: F821
    snakemake.params.image_set,  # noqa: F821
    snakemake.params.samples_per_pixel,  # noqa: F821
    snakemake.params.mitsuba_variant,  # noqa: F821
    snakemake.output.images,  # noqa: F821
    threads=snakemake.threads,  # noqa: F821
    surface_map=snakemake.params.surface_map,  # noqa: F821
    light_out_of_plane_deg=snakemake.params.light_out_of_plane_deg,  # noqa: F821
    relief_spec=snakemake.params.relief,  # noqa: F821
)
