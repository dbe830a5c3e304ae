"""What the benchmarks share: the best time of repeated calls."""

from __future__ import annotations

import time


def best_of(repeats: int, call):
    """The shortest wall time, in seconds, of ``repeats`` calls of ``call`` (at least one), and the last call's result."""
    best, result = float("inf"), None
    for _ in range(max(repeats, 1)):
        tick = time.perf_counter()
        result = call()
        best = min(best, time.perf_counter() - tick)
    return best, result
