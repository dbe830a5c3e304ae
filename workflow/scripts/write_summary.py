"""Rule script: results/summary.md, the headline numbers of the run's tables with its commit and config."""

import logging
import subprocess
from pathlib import Path

import _workflow_path  # noqa: F401 (puts the library on sys.path)
from asteroid_photometry.evaluation.summary import TABLES, sha256_of, write_summary
from asteroid_photometry.logs import setup_logging

log = logging.getLogger(__name__)


def workflow_commit() -> str:
    """The commit of the workflow's own checkout, or "unknown" when it is not a git checkout (or git is missing)."""
    try:
        result = subprocess.run(
            ["git", "-C", str(Path(__file__).resolve().parents[2]), "rev-parse", "HEAD"],
            capture_output=True, text=True, timeout=30, check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return result.stdout.strip() if result.returncode == 0 and result.stdout.strip() else "unknown"


setup_logging(snakemake.log[0])  # noqa: F821 (set by Snakemake's script: directive)
tables = {name: snakemake.input[name] for name in TABLES if name in snakemake.input.keys()}  # noqa: F821
commit = workflow_commit()
write_summary(
    tables,
    snakemake.output[0],  # noqa: F821
    config=snakemake.params.config,  # noqa: F821
    commit=commit,
    config_files={path: sha256_of(path) for path in snakemake.params.configfiles},  # noqa: F821
    paper_table1=snakemake.input.paper,  # noqa: F821
)
log.info("summary of %s written (commit %s)", ", ".join(tables), commit)
