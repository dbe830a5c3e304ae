"""The memory allocator every job of the workflow runs with: large arrays reused, not mapped afresh.

glibc's malloc gives every block of 32 MiB or more (less, by default) its own
``mmap`` and hands it back to the system when it is freed, so that the next
array of that size starts from untouched pages and pays a page fault every
4 KiB. The Table 2 stages build and drop arrays of hundreds of megabytes at
every step (the mesh fit's Jacobian, normal matrix and blur; the
refinement's samples), and on a 2-core machine those faults were a tenth to a
sixth of a mesh fit's time (bench/bench_allocator.py). With ``mmap`` off for
the heap and no trimming of its top, freed memory stays in the process and
the next array reuses it. The answer is the same to the bit (the same
arithmetic, other addresses); a job's peak memory is what its largest
moment needs, as before, but the memory stays the job's until it ends.

The Snakefile sets these in its own environment, which every job it starts
inherits (locally and through a cluster executor that passes the
submitting environment on); a value the user set wins. They are glibc's
documented environment variables, read when a process starts; another C
library ignores them.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

#: No ``mmap`` for the heap's blocks (they come from its top instead), and the top never trimmed (64 GiB).
ALLOCATOR_ENV = {"MALLOC_MMAP_MAX_": "0", "MALLOC_TRIM_THRESHOLD_": str(64 * 2**30)}


def with_allocator_env(environ: MutableMapping[str, str] | None = None) -> MutableMapping[str, str]:
    """``environ`` (default: this process's, changed in place) with ``ALLOCATOR_ENV``'s variables where unset."""
    environ = os.environ if environ is None else environ
    for key, value in ALLOCATOR_ENV.items():
        environ.setdefault(key, value)
    return environ
