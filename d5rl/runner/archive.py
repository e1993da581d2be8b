"""What a grid brings back from a machine it cannot keep: every result file, then checkpoints while they fit.

``python -m d5rl.runner.archive RUN_DIR [--budget-mib 56]`` prints the files to pack, relative to RUN_DIR,
one a line (for ``tar -T``), and a summary on stderr; ``scripts/gpu_bench.sh`` packs its cells with it.
RUN_DIR is a bench output directory (``TASK/ALGO/seedN`` below it) or a folder of them.  Result files
(logs, metrics, summaries, ``done`` markers) always come; checkpoints follow in this order while the total
stays within the budget: each task's best finished cell (the one the report's rollout GIF is made from,
:func:`d5rl.runner.videos.ranked_cells`), then the unfinished cells (to resume or evaluate them elsewhere).
Locks, worker records, TensorBoard event files and a checkpoint's previous or half-written copies never
come.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from d5rl.runner.results import collect
from d5rl.runner.videos import ranked_cells
from d5rl.training.rundir import CHECKPOINT, CHECKPOINT_TMP_PREFIX, NOT_ARCHIVED, RunDir


def _skipped(rel: Path) -> bool:
    return any(p == CHECKPOINT or p in NOT_ARCHIVED or p.startswith(CHECKPOINT_TMP_PREFIX) for p in rel.parts)


def _files(d: Path) -> list[Path]:
    return sorted(p for p in d.rglob("*") if p.is_file())


def archive_files(run_dir: Path | str, budget_bytes: int) -> tuple[list[Path], list[Path]]:
    """``(files, cells whose checkpoint is included)``; files are relative to ``run_dir``."""
    root = Path(run_dir)
    files = [p for p in _files(root) if not _skipped(p.relative_to(root))]
    size = sum(p.stat().st_size for p in files)
    results = [r for d in [root, *sorted(p for p in root.iterdir() if p.is_dir())] for r in collect(d)]
    tasks = sorted({r.task for r in results})
    best = [ranked[0].directory for task in tasks if (ranked := ranked_cells(results, task))]
    unfinished = [r.directory for r in results if not r.done]
    kept = []
    for cell_dir in best + unfinished:
        latest = RunDir(cell_dir).checkpoint
        ckpt = _files(latest) if latest.is_dir() else []
        extra = sum(p.stat().st_size for p in ckpt)
        if ckpt and size + extra <= budget_bytes:  # (best cells are finished: the two lists are disjoint)
            files += ckpt
            size += extra
            kept.append(cell_dir)
    return [p.relative_to(root) for p in files], kept


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m d5rl.runner.archive", description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--budget-mib", type=float, default=56.0, help="at most this much in all (default 56)")
    args = ap.parse_args(argv)
    if not args.run_dir.is_dir():
        print(f"error: {args.run_dir} is not a directory", file=sys.stderr)
        return 2
    files, kept = archive_files(args.run_dir, int(args.budget_mib * 2**20))
    print("\n".join(str(p) for p in files))
    total = sum((args.run_dir / p).stat().st_size for p in files)
    print(f"archive: {len(files)} files, {total / 2**20:.1f} MiB, checkpoints of {len(kept)} cells", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
