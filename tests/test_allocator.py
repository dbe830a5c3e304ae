"""The jobs' memory allocator setting (core/allocator.py): set where unset, the user's value kept, and it keeps freed memory."""

import os
import subprocess
import sys

from asteroid_photometry.core.allocator import ALLOCATOR_ENV, with_allocator_env

# A child that fills a 256 MiB array, frees it and reports how much of it the process still holds (KiB).
_HELD_AFTER_FREE = """
import numpy as np
def rss():
    return int(next(line for line in open("/proc/self/status") if line.startswith("VmRSS")).split()[1])
before = rss()
block = np.ones(32 * 2**20)
del block
print(rss() - before)
"""


def _held_kib(env):
    out = subprocess.run([sys.executable, "-c", _HELD_AFTER_FREE], env=env, capture_output=True, text=True, check=True)
    return int(out.stdout)


def test_set_where_unset_and_the_users_value_wins():
    assert with_allocator_env({}) == ALLOCATOR_ENV
    environ = with_allocator_env({"MALLOC_MMAP_MAX_": "65536", "PATH": "/bin"})
    assert environ["MALLOC_MMAP_MAX_"] == "65536" and environ["PATH"] == "/bin"
    assert environ["MALLOC_TRIM_THRESHOLD_"] == ALLOCATOR_ENV["MALLOC_TRIM_THRESHOLD_"]


def test_the_setting_keeps_a_freed_array_for_reuse():
    """glibc reads the variables: without them a freed 256 MiB array goes back to the system at once (its own mapping);
    with them the process keeps it, for the next array to reuse without page faults."""
    plain = {key: value for key, value in os.environ.items() if key not in ALLOCATOR_ENV}
    assert _held_kib(plain) < 32 * 1024
    assert _held_kib(with_allocator_env(dict(plain))) > 200 * 1024


def test_the_snakefile_sets_it_for_its_jobs():
    """The Snakefile's helpers call it where they are read, so every job started inherits it."""
    from pathlib import Path

    common = (Path(__file__).resolve().parents[1] / "workflow" / "rules" / "common.smk").read_text()
    assert "\nwith_allocator_env()\n" in common
