"""What is on disk for a task's dataset, in one word (for ``d5rl list`` / ``info`` and the browse page)."""

from __future__ import annotations

from pathlib import Path

from d5rl.datasets import format as fmt
from d5rl.datasets import generation
from d5rl.errors import D5RLError


def dataset_status(spec) -> tuple[str, dict | None]:
    """``(status, manifest)``: "ready", "partial (N ep)", "stale (...)", "not generated", ... and the
    manifest when one could be read."""
    if spec.dataset is None:
        return "-", None
    if spec.dataset.unavailable:
        return "unavailable (data agents not trained)", None
    root = generation.dataset_root(spec.dataset)
    path = root / fmt.MANIFEST
    if path.exists():
        try:
            m = fmt.read_manifest(path)
        except D5RLError:
            return "unreadable manifest (generate --force)", None
        try:
            generation.check_current(m, spec.dataset, spec.dataset.default_seed, root)
        except D5RLError:
            return ("stale (import again)" if spec.dataset.imported else "stale (generate --force)"), m
        full = spec.dataset.imported or m["num_episodes"] >= spec.dataset.num_episodes
        return ("ready" if full else f"partial ({m['num_episodes']} ep)"), m
    if spec.dataset.imported:
        return "not imported", None
    if (root / "shards").exists():
        return "incomplete (resume with generate)", None
    return "not generated", None


def disk_bytes(root: Path) -> int:
    """Bytes of every file under ``root`` (dataset, derived caches)."""
    return sum(p.stat().st_size for p in Path(root).rglob("*") if p.is_file())


def human_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TiB"
