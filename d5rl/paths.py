"""Where d5rl keeps generated data.

``$D5RL_HOME`` overrides the default ``~/.cache/d5rl`` (or ``$XDG_CACHE_HOME/d5rl``).
"""

from __future__ import annotations

import os
from pathlib import Path


def home() -> Path:
    """Root of the d5rl cache (datasets, render caches)."""
    env = os.environ.get("D5RL_HOME")
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "d5rl"


def datasets_dir() -> Path:
    return home() / "datasets"
