"""``python -m d5rl.runner.worker SPEC.json``: run one cell in a fresh process (the local backend).

The exit code tells the sweep what happened (:data:`d5rl.runner.execute.EXIT_CODES`);
the details are in the cell directory.
"""

from __future__ import annotations

import contextlib
import json
import sys


def _die_with_parent() -> None:
    """Linux: SIGKILL this worker when the sweep process dies, so no orphan races a resumed sweep."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes
            import signal

            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG


def main(argv: list[str] | None = None) -> int:
    _die_with_parent()
    argv = sys.argv[1:] if argv is None else argv
    with open(argv[0]) as f:
        spec = json.load(f)
    from d5rl.runner.execute import EXIT_CODES, configure_worker  # light imports only

    configure_worker(spec.get("single_thread", True), spec.get("nice", 0))  # before JAX is imported
    for p in reversed(spec.get("sys_path", [])):  # the caller's import path (its jobs, test modules)
        if p not in sys.path:
            sys.path.insert(0, p)
    from d5rl.runner.execute import execute_cell

    result = execute_cell(spec["cell"], spec["cell_dir"], spec["attempt"])
    return EXIT_CODES[result["status"]]


if __name__ == "__main__":
    sys.stdout.flush()
    sys.exit(main())
