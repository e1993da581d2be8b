"""Integrity check of a generated dataset: every file present, every checksum right, and made by this code
from the inputs it would use now (its identity)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from d5rl.datasets import format as fmt
from d5rl.datasets.generation import check_current, dataset_root, dataset_spec
from d5rl.errors import D5RLError
from d5rl.progress import progress_bar
from d5rl.registry import TaskSpec, get_spec, resolve


@dataclasses.dataclass
class VerifyReport:
    root: Path
    shards_checked: int
    problems: list[str]

    @property
    def ok(self) -> bool:
        return not self.problems


def regenerate_command(task_id: str, seed: int | None = None) -> str:
    """The command that regenerates what verification finds missing or damaged (intact shards are kept);
    for an imported dataset, the command that imports it again."""
    dspec = get_spec(task_id).dataset
    if dspec is not None and dspec.imported:
        return resolve(dspec.importer).command
    return f"d5rl generate {task_id}" + (f" --seed {seed}" if seed is not None else "")


def verify_dataset(task: str | TaskSpec, seed: int | None = None, progress: bool = False) -> VerifyReport:
    """Re-hash every array of the dataset (and its derived caches) against its records."""
    spec = get_spec(task)
    root = dataset_root(dataset_spec(spec), seed)
    problems: list[str] = []
    manifest_path = root / fmt.MANIFEST
    if not manifest_path.exists():
        hint = (
            "generation did not finish"
            if (root / "shards").exists()
            else "it was never imported"
            if spec.dataset.imported
            else "it was never generated"
        )
        return VerifyReport(root, 0, [f"{manifest_path}: missing ({hint}; run `{regenerate_command(spec.id, seed)}`)"])
    try:
        manifest = fmt.read_manifest(manifest_path)
    except D5RLError as e:
        return VerifyReport(root, 0, [e.message])
    dspec = dataset_spec(spec)
    try:  # intact bytes of other data (older code, other settings, other policy files) are not this dataset
        check_current(manifest, dspec, dspec.default_seed if seed is None else seed, root)
    except D5RLError as e:
        problems.append(str(e))  # with its hint: `generate --force`, not the plain repair below
    entries = manifest.get("shards", [])
    dirs = [(root / "shards" / e["name"], e) for e in entries]
    for render_root in sorted((root / "renders").glob("*")) if (root / "renders").exists() else []:
        dirs += [(d, None) for d in fmt.iter_shard_dirs(render_root)]
    it = dirs
    if progress:
        it = progress_bar(dirs, unit="shard", desc=f"verify {root.parent.name}")
    for d, entry in it:
        problems += fmt.verify_shard(d, entry)
    if entries and manifest.get("num_episodes") != entries[-1]["episodes"][1]:
        problems.append(
            f"{manifest_path}: num_episodes {manifest.get('num_episodes')} "
            f"disagrees with its last shard {entries[-1]['episodes']}"
        )
    return VerifyReport(root, len(dirs), problems)
