"""Paths asked for by the page: resolved (``..``, symlinks) and served only when they lie inside one of
the allowed roots ($D5RL_HOME, the run directories given on the command line)."""

from __future__ import annotations

from pathlib import Path

from d5rl.errors import D5RLError


class NotAllowed(D5RLError):
    """A path outside every allowed root, or of a kind the page may not read."""


def inside(path: str | Path, roots: list[Path]) -> Path:
    """``path`` resolved (symlinks followed); :class:`NotAllowed` unless it is inside one of ``roots``."""
    resolved = Path(path).resolve()
    for root in roots:
        if resolved.is_relative_to(Path(root).resolve()):
            return resolved
    raise NotAllowed(f"{path} is outside the directories this page may read")


def file_under(root: Path, relative: str, suffixes: tuple[str, ...]) -> Path:
    """The existing file ``root/relative`` with one of ``suffixes``; :class:`NotAllowed` for absolute paths,
    paths that leave ``root`` (``..``, symlinks pointing out) and other kinds of file."""
    if not relative or Path(relative).is_absolute() or "\\" in relative or "\x00" in relative:
        raise NotAllowed(f"{relative!r} is not a relative path")
    path = inside(Path(root) / relative, [Path(root)])
    if path.suffix.lower() not in suffixes or not path.is_file():
        raise NotAllowed(f"{relative!r} is not a {'/'.join(suffixes)} file of {root}")
    return path
