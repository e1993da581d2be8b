"""``python -m d5rl.runner bench|report ...``: the same subcommands as ``d5rl bench`` / ``d5rl report``."""

from __future__ import annotations

import argparse
import sys

from d5rl.errors import D5RLError
from d5rl.runner.cli import add_bench_parser, add_report_parser


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m d5rl.runner")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_bench_parser(sub)
    add_report_parser(sub)
    args = p.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except D5RLError as e:
        print(f"error: {e.message}", file=sys.stderr)
        if e.hint:
            print(f"  hint: {e.hint}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
