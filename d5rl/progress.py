"""Progress bars: tqdm on a terminal; into a log file, an update at most every 30 seconds.

``d5rl bench`` cells, background jobs and CI write stderr to files, where tqdm's ten redraws a
second become megabytes of carriage returns (a cell's ``log.txt`` is committed with its results).
"""

from __future__ import annotations

import sys

LOG_INTERVAL = 30.0  # seconds between updates when stderr is not a terminal

_enabled = True


def set_enabled(enabled: bool) -> None:
    """Turn every bar of this process on or off (``d5rl COMMAND --no-progress`` turns them off)."""
    global _enabled
    _enabled = bool(enabled)


def progress_bar(iterable=None, **kwargs):
    """``tqdm(iterable, **kwargs)``, slowed to one update per :data:`LOG_INTERVAL` off a terminal, hidden
    after :func:`set_enabled` ``(False)``."""
    from tqdm.auto import tqdm

    if not _enabled:
        kwargs["disable"] = True

    if not _stderr_is_terminal():
        kwargs["mininterval"] = max(float(kwargs.get("mininterval", 0.1)), LOG_INTERVAL)
        kwargs.pop("dynamic_ncols", None)  # no terminal to size to
        kwargs.setdefault("ncols", 100)
    return tqdm(iterable, **kwargs)


def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stream
        return False
