"""Shared pytest set-up: the library on sys.path and the shared Itokawa data."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "workflow"))
# Rule scripts import _workflow_path from their own directory, as under Snakemake.
sys.path.insert(1, str(Path(__file__).parents[1] / "workflow" / "scripts"))


@pytest.fixture(scope="session")
def shared_itokawa_dir():
    """The shared Itokawa shape files (../shared/data/itokawa beside the repository); skip if absent."""
    itokawa_dir = Path(__file__).parents[2] / "shared" / "data" / "itokawa"
    if not itokawa_dir.is_dir():
        pytest.skip(f"shared Itokawa data not found at {itokawa_dir}")
    return itokawa_dir
