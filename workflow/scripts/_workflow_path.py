"""Imported first by every rule script: puts the ``asteroid_photometry`` library on ``sys.path``.

Snakemake adds this scripts/ directory to the path of a script job; the
library lives one level up, in workflow/.
"""

import sys
from pathlib import Path

_WORKFLOW_DIR = str(Path(__file__).resolve().parents[1])
if _WORKFLOW_DIR not in sys.path:
    sys.path.insert(0, _WORKFLOW_DIR)
