"""Rule script: results/summary.md, the headline numbers of the run's tables with its commit and config."""

import logging
from pathlib import Path

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.evaluation.summary import TABLES, git_commit, sha256_of, write_summary
from asteroid_photometry.core.logs import setup_logging

log = logging.getLogger(__name__)


setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
tables = {name: snakemake.input[name] for name in TABLES if name in snakemake.input.keys()}  # noqa: F821
# The commit of the workflow's own checkout (the repository this script is in).
commit = git_commit(Path(__file__).resolve().parents[2])
write_summary(
    tables,
    snakemake.output[0],  # noqa: F821
    config=snakemake.params.config,  # noqa: F821
    commit=commit,
    config_files={path: sha256_of(path) for path in snakemake.params.configfiles},  # noqa: F821
    paper_table1=snakemake.input.paper,  # noqa: F821
)
log.info("summary of %s written (commit %s)", ", ".join(tables), commit)
