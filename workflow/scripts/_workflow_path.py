"""Imported first by every rule script: puts the ``asteroid_photometry`` library on ``sys.path``.

Snakemake adds this scripts/ directory to the path of a script job; the
library lives one level up, in workflow/.
"""

import os
import sys
from pathlib import Path

# Parallelism comes from Snakemake's jobs; a multi-threaded BLAS inside every
# job only fights over the cores (the estimators' many small solves slow down
# up to tenfold). A value set by the user wins.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

_WORKFLOW_DIR = str(Path(__file__).resolve().parents[1])
if _WORKFLOW_DIR not in sys.path:
    sys.path.insert(0, _WORKFLOW_DIR)
