"""Writing files so that a reader or a crash never sees half of one: write a uniquely named temporary
file next to the target, fsync it, rename it over the target (atomic on POSIX)."""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import Any

import numpy as np


def owner_tag() -> str:
    """``<host>-<pid>-<random>``: unique per writer, and says which process to ask whether it is alive."""
    return f"{socket.gethostname()}-{os.getpid()}-{os.urandom(4).hex()}"


def write_atomic(path: str | Path, data: str | bytes) -> None:
    """Replace ``path`` with ``data`` in one step (durable before it becomes visible)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{owner_tag()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def dump_json(obj: Any, path: str | Path, indent: int = 1) -> None:
    """Deterministic JSON (sorted keys; numpy scalars and arrays as plain values), written atomically."""
    write_atomic(path, json.dumps(obj, indent=indent, sort_keys=True, default=json_default) + "\n")


def json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serializable")
