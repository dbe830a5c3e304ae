"""The memory allocator every job of the workflow runs with: large arrays reused, not mapped afresh.

glibc's malloc gives every block of 32 MiB or more (less, by default) its own
``mmap`` and hands it back to the system when it is freed, so that the next
array of that size starts from untouched pages and pays a page fault every
4 KiB. The Table 2 stages build and drop arrays of hundreds of megabytes at
every step (the mesh fit's Jacobian, normal matrix and blur; the
refinement's samples). With ``mmap`` off for the heap and no trimming of its
top, freed memory stays in the process and the next array reuses it. On a
2-core machine a mesh fit alone took 0.96 of its time and the refinement 0.93
(bench/bench_allocator.py; four mesh fits of paper sets 0.92); the answer is
the same to the bit (the same arithmetic, other addresses). The price is
memory: a freed block stays the job's until it ends, and the heap fragments,
so a full run's mesh fits peaked 1.09 to 1.50 times as high
(docs/running.md, "How long it takes"); other stages within 1 %.

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
