"""``python -m d5rl.runner.worker SPEC.json``: run one cell in a fresh process (the local backend).

The exit code tells the sweep what happened (:data:`d5rl.runner.execute.EXIT_CODES`);
the details are in the cell directory.
"""

from __future__ import annotations

import json
import sys


def main(argv: list[str] | None = None) -> int:
    from d5rl.parallel import configure_worker, die_with_parent  # light imports only

    die_with_parent()  # no orphan races a resumed sweep
    argv = sys.argv[1:] if argv is None else argv
    with open(argv[0]) as f:
        spec = json.load(f)
    configure_worker(spec.get("single_thread", True), spec.get("nice", 0))  # before JAX is imported
    from d5rl.runner.execute import EXIT_CODES

    for p in reversed(spec.get("sys_path", [])):  # the caller's import path (its jobs, test modules)
        if p not in sys.path:
            sys.path.insert(0, p)
    from d5rl.runner.execute import execute_cell

    result = execute_cell(spec["cell"], spec["cell_dir"], spec["attempt"])
    return EXIT_CODES[result["status"]]


if __name__ == "__main__":
    sys.stdout.flush()
    sys.exit(main())
