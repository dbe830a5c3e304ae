"""Shared pytest set-up: the library on sys.path and the Itokawa shape models that ship with the workflow."""

import lzma
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parents[1] / "workflow"))
# Rule scripts import _workflow_path from their own directory, as under Snakemake.
sys.path.insert(1, str(Path(__file__).parents[1] / "workflow" / "scripts"))

from asteroid_photometry.world.shape import SHAPE_MODELS  # noqa: E402

# The file names the models have in their source archives.
ARCHIVE_NAMES = {"gaskell_ver64q": "itokawa_low.obj", "ostro_radar": "25143itokawa.tab"}


@pytest.fixture(scope="session")
def itokawa_dir(tmp_path_factory):
    """The shipped shape models decompressed under their archive names (itokawa_low.obj, 25143itokawa.tab)."""
    directory = tmp_path_factory.mktemp("itokawa")
    for name, file_name in ARCHIVE_NAMES.items():
        (directory / file_name).write_bytes(lzma.decompress(SHAPE_MODELS[name].shipped_path.read_bytes()))
    return directory
