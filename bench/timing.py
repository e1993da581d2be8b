"""The timing helper the bench scripts share (they add the repository root to ``sys.path``)."""

from __future__ import annotations

import time


def rate(fn, seconds: float) -> float:
    """Calls of ``fn()`` per second: one warm-up call (compilation, caches), then calls until ``seconds`` pass."""
    fn()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        fn()
        n += 1
    return n / (time.perf_counter() - t0)
