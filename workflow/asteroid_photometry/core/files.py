"""Writing outputs whole or not at all: a temporary name in the same directory, then a rename.

A job killed halfway (SIGKILL, a lost node) leaves at most a hidden
``.<name>.partial`` file or directory beside its output, never a truncated
output under the real name; the next run of the same job writes the same
temporary name again and renames it into place. Snakemake reruns the
killed job itself (``--rerun-incomplete``); these helpers keep the files a
job writes inside an output directory, and files read outside Snakemake,
from ever being seen half-written.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

PARTIAL = ".partial"


def partial_path(path) -> Path:
    """The name ``path`` is written under until it is complete: hidden, same directory, same suffix."""
    path = Path(path)
    return path.with_name(f".{path.stem}{PARTIAL}{path.suffix}")


@contextlib.contextmanager
def replacing(path):
    """Yield a temporary path beside ``path``; renamed to ``path`` when the block ends without an error, removed otherwise."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    part = partial_path(path)
    try:
        yield part
        os.replace(part, path)
    finally:
        part.unlink(missing_ok=True)


def partial_directory(path) -> Path:
    """An empty hidden directory beside ``path`` to write its contents into; :func:`move_into_place` then renames it to ``path``."""
    path = Path(path)
    part = path.with_name(f".{path.name}{PARTIAL}")
    shutil.rmtree(part, ignore_errors=True)  # a killed run's
    part.mkdir(parents=True)
    return part


def move_into_place(part, path) -> None:
    """Rename the complete directory ``part`` to ``path``, replacing what was there."""
    path = Path(path)
    if path.is_dir():
        shutil.rmtree(path)
    os.replace(part, path)


def write_text(path, text: str) -> None:
    with replacing(path) as part:
        part.write_text(text)


def write_json(path, value, indent: int = 1) -> None:
    write_text(path, json.dumps(value, indent=indent))


def write_csv(table, path) -> None:
    """A pandas table as CSV, without its index."""
    with replacing(path) as part:
        table.to_csv(part, index=False)


def savez(path, **arrays) -> None:
    """``np.savez_compressed`` to ``path`` (which should end in .npz)."""
    with replacing(path) as part, open(part, "wb") as handle:  # a handle: np.savez appends .npz to other names
        np.savez_compressed(handle, **arrays)


def save_figure(figure, path, **kwargs) -> None:
    """``figure.savefig`` to ``path``, the format from its suffix."""
    with replacing(path) as part:
        figure.savefig(part, **kwargs)
