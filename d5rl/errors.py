"""Errors that d5rl raises for bad input or bad files.

Every error says what went wrong *and what to do*.  The CLI prints them as one
line, without a traceback; library users can catch :class:`D5RLError`.
"""

from __future__ import annotations

import numbers


class D5RLError(Exception):
    """Base class: a problem the user can fix.  ``hint`` says how."""

    def __init__(self, message: str, hint: str | None = None):
        self.message = message
        self.hint = hint
        super().__init__(str(self))

    def __str__(self) -> str:  # the same one line for every subclass (KeyError's would quote it)
        return self.message if self.hint is None else f"{self.message} (hint: {self.hint})"


class UnknownTaskError(D5RLError, KeyError):
    """A task id that no family registers."""


class TaskIdError(D5RLError, ValueError):
    """A string that does not follow the ``<family>-<name>-v<N>`` grammar."""


class DatasetNotFoundError(D5RLError, FileNotFoundError):
    """The dataset has not been generated (or not with enough episodes)."""


class DatasetArgumentError(D5RLError, TypeError, ValueError):
    """A keyword argument that a task's dataset does not take, or a value it cannot use."""


class DatasetCorruptError(D5RLError):
    """A dataset file is missing, truncated or fails its checksum."""


class DatasetVersionError(D5RLError):
    """A dataset on disk was written by another format or dataset version."""


class MissingAssetError(D5RLError, FileNotFoundError):
    """A robot/scene model package is not installed."""


class RenderBackendError(D5RLError, RuntimeError):
    """No working headless OpenGL backend."""


class MissingDependencyError(D5RLError, ImportError):
    """An optional dependency (an extra) is not installed."""


def is_int(value, lo: int | None = None, hi: int | None = None) -> bool:
    """Whether ``value`` is an integer (Python's or NumPy's; a bool is not) in ``[lo, hi]``: the check behind the
    seeds, counts, frame sizes, ports and worker numbers that d5rl validates before work starts (config values
    have :class:`d5rl.agents.config.Bound`)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        return False
    return bool((lo is None or value >= lo) and (hi is None or value <= hi))
