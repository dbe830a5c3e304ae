"""Rule script: Table 2 as CSV and as Markdown beside the paper's."""

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.core.logs import setup_logging
from asteroid_photometry.experiments.table2_scoring import write_table2

setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
write_table2(snakemake.input.summaries, snakemake.output.csv, snakemake.output.markdown)  # noqa: F821
