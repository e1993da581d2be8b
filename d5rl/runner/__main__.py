"""``python -m d5rl.runner bench|report ...``: the same as ``d5rl bench`` / ``d5rl report`` (one CLI)."""

from __future__ import annotations

import sys

from d5rl.cli import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
