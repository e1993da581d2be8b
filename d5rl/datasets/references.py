"""Reference fingerprints: what every registered dataset's bytes are, so a copy can be checked.

``references.json`` (next to this module) holds, per dataset (at its default seed), the per-array
sha256 of its first shard and a digest of every array of every episode in it; of the whole dataset for
the toy family (generated whole by the test suite) and for the datasets our published results trained
on where we generated them whole (``WHOLE``). Each entry records the dataset's
numerics and the machine it was made on: a ``portable`` dataset (:mod:`d5rl.numerics`) has the
same bytes on every x86-64 CPU, a ``native`` one only on the machine class recorded.

    d5rl verify TASK --reference          # "identical to the reference", or the first difference
    python -m d5rl.datasets.references    # regenerate every reference (first shards, in a temp dir)
    python -m d5rl.datasets.references a1-v1-locomotion --home ~/.cache/d5rl   # from a copy made already
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from d5rl import numerics
from d5rl.datasets import format as fmt
from d5rl.datasets.generation import dataset_root, dataset_spec, generate
from d5rl.errors import D5RLError
from d5rl.files import dump_json
from d5rl.registry import get_spec, list_tasks

REFERENCES = Path(__file__).with_name("references.json")
TOY = ("toy-reach", "toy-reach-pixels")  # generated whole by the test suite
# referenced whole: the data of the published v1 A1 cells (and of the BC runs that chose the hiking data)
WHOLE = TOY + ("a1-v1-locomotion", "a1-v1-hiking", "a1-v1-hiking-smooth")
DIGEST_HEX = 16  # per-episode digests: 64 bits tell which episode differs, at a quarter of the size


def load_references(path: Path = REFERENCES) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}


def _episode_slices(lengths: list[int], align: str) -> list[tuple[int, int]]:
    """Row ranges of each episode in a shard array (step-aligned arrays have one row more per episode)."""
    out, a = [], 0
    for n in lengths:
        b = a + n + (align == "step")
        out.append((a, b))
        a = b
    return out


def episode_digests(shard_dir: Path, record: dict) -> dict[str, list[str]]:
    """Per array, a digest of each episode's rows (dtype, shape and bytes) in one shard."""
    out = {}
    for key, info in sorted(record["arrays"].items()):
        arr = fmt.open_array(shard_dir, info)
        digests = []
        for a, b in _episode_slices(record["episode_lengths"], info["align"]):
            rows = np.ascontiguousarray(arr[a:b])
            h = hashlib.sha256(f"{rows.dtype.str}{rows.shape}".encode())
            h.update(rows.tobytes())
            digests.append(h.hexdigest()[:DIGEST_HEX])
        out[key] = digests
    return out


def make_entry(root: Path, num_shards: int | None, machine: str) -> dict:
    """The reference of a generated dataset: its first ``num_shards`` shards (None: all), hashed from
    the files themselves (not from the records they carry)."""
    manifest = fmt.read_manifest(root / fmt.MANIFEST)
    entries = manifest["shards"][:num_shards]
    shards, episodes = [], {}
    for entry in entries:
        shard_dir = root / "shards" / entry["name"]
        record = fmt.read_shard_record(shard_dir)
        shards.append(
            {
                "name": entry["name"],
                "episodes": entry["episodes"],
                "arrays": {
                    k: fmt.sha256_file(shard_dir / info["file"]) for k, info in sorted(record["arrays"].items())
                },
            }
        )
        for key, digests in episode_digests(shard_dir, record).items():
            episodes.setdefault(key, []).extend(digests)
    return {
        **{k: manifest[k] for k in ("dataset_version", "generator", "generator_version", "seed")},
        "numerics": manifest.get("numerics", "native"),
        "machine": machine,
        "packages": manifest.get("packages", {}),
        "num_episodes": entries[-1]["episodes"][1],
        "shards": shards,
        "episodes": episodes,
    }


@dataclasses.dataclass
class Comparison:
    identical: bool
    message: str


def compare(root: Path, ref: dict) -> Comparison:
    """``root``'s dataset against the reference entry ``ref``: identical on the episodes both have, or
    the first difference (in episode order, then array name)."""
    manifest = fmt.read_manifest(root / fmt.MANIFEST)
    name = manifest["dataset"]
    mine = {k: manifest.get(k) for k in ("dataset_version", "generator_version", "seed")}
    theirs = {k: ref.get(k) for k in mine}
    if mine != theirs:
        return Comparison(
            False,
            f"the reference of {name} is of {theirs}; this dataset is {mine}: "
            "they describe different data (regenerate the reference: "
            f"`python -m d5rl.datasets.references {name}`)",
        )
    where = (
        f"reference: {ref['numerics']} numerics, made on {ref['machine']}; "
        f"this copy: {manifest.get('numerics', 'native')} numerics"
    )
    whole = {s["name"]: s for s in ref["shards"]}
    n = min(manifest["num_episodes"], ref["num_episodes"])
    for shard in manifest["shards"]:
        a, b = shard["episodes"]
        if a >= n:
            break
        same = whole.get(shard["name"], {})
        if same.get("episodes") == [a, b] and same["arrays"] == {k: v["sha256"] for k, v in shard["arrays"].items()}:
            continue  # the whole shard is byte-identical: no need to read it
        shard_dir = root / "shards" / shard["name"]
        digests = episode_digests(shard_dir, fmt.read_shard_record(shard_dir))
        if sorted(digests) != sorted(ref["episodes"]):
            return Comparison(
                False, f"{name} has arrays {sorted(digests)}, the reference {sorted(ref['episodes'])} ({where})"
            )
        for i in range(a, min(b, n)):
            for key in sorted(digests):
                if digests[key][i - a] != ref["episodes"][key][i]:
                    return Comparison(
                        False,
                        f"differs from the reference: first in array '{key}', episode {i} "
                        f"(in {shard['name']}) ({where})",
                    )
    more = (
        f"; the reference covers {ref['num_episodes']}: generate them to compare all" if n < ref["num_episodes"] else ""
    )
    first = "the first episode" if n == 1 else f"the first {n} episodes"
    return Comparison(
        True, f"identical to the reference: {first} of {name}, {len(ref['episodes'])} arrays{more} ({where})"
    )


def compare_task(task, seed: int | None = None, references: dict | None = None) -> Comparison:
    """The dataset of ``task`` on disk (at ``seed``) against its committed reference."""
    dspec = dataset_spec(task)
    refs = load_references() if references is None else references
    if dspec.name not in refs:
        raise D5RLError(
            f"no reference fingerprint is recorded for {dspec.name}",
            f"record one: `python -m d5rl.datasets.references {dspec.name}`",
        )
    if seed is not None and seed != refs[dspec.name]["seed"]:
        raise D5RLError(
            f"the reference of {dspec.name} is of seed {refs[dspec.name]['seed']}, not {seed}",
            "leave out --seed to check the default-seed dataset",
        )
    root = dataset_root(dspec, seed)
    if not (root / fmt.MANIFEST).exists():
        raise D5RLError(
            f"{root} has no finished dataset to compare",
            f"generate it first: `d5rl generate {getattr(task, 'id', task)}`",
        )
    return compare(root, refs[dspec.name])


def dataset_tasks() -> dict[str, str]:
    """Every dataset of d5rl's task families that d5rl can generate now, with the first task (by id) that
    uses it. Without a reference: imported datasets (their bytes are a download's), datasets marked
    unavailable (e.g. their data agents are not trained yet) and tasks registered from outside d5rl."""
    out = {}
    for task in list_tasks():
        spec = get_spec(task)
        d = spec.dataset
        if (
            d is not None
            and d.name not in out
            and spec.entry_point.startswith("d5rl.")
            and not d.imported
            and d.unavailable is None
        ):
            out[d.name] = task
    return out


def record(names: list[str], path: Path = REFERENCES, workers: int = 1, home: Path | None = None) -> None:
    """Generate each dataset's reference (its first shard; ``WHOLE`` ones whole) and write its entry: in a
    temporary ``D5RL_HOME``, or in ``home``, where a copy already made is verified and used as it is."""
    tasks = dataset_tasks()
    unknown = [n for n in names if n not in tasks]
    if unknown:
        raise D5RLError(f"unknown dataset(s) {unknown}", f"known: {', '.join(sorted(tasks))}")
    if home is not None and not Path(home).is_dir():
        raise D5RLError(f"--home {home} is not a directory", "name the D5RL_HOME that holds the datasets")
    refs = load_references(path)
    machine = numerics.machine()
    for name in names:
        dspec = dataset_spec(tasks[name])
        whole = name in WHOLE
        with tempfile.TemporaryDirectory(prefix="d5rl-reference-") as tmp:
            old = os.environ.get("D5RL_HOME")
            os.environ["D5RL_HOME"] = str(home or tmp)
            try:
                t0 = time.perf_counter()
                root = generate(  # a finished copy in ``home`` is verified and kept
                    tasks[name],
                    num_episodes=None if whole else dspec.episodes_per_shard,
                    workers=workers,
                    progress=False,
                )
                refs[name] = make_entry(root, None if whole else 1, machine)
                print(
                    f"{name}: {refs[name]['num_episodes']} episodes, {refs[name]['numerics']} numerics, "
                    f"{time.perf_counter() - t0:.0f} s",
                    flush=True,
                )
            finally:
                if old is None:
                    os.environ.pop("D5RL_HOME", None)
                else:
                    os.environ["D5RL_HOME"] = old
        dump_json(dict(sorted(refs.items())), path)  # after each dataset: a long run keeps what it made


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m d5rl.datasets.references",
        description="regenerate reference fingerprints (first shard; the datasets in WHOLE whole)",
    )
    ap.add_argument("datasets", nargs="*", help="dataset names (default: every registered dataset)")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--out", type=Path, default=REFERENCES, help="the references file to update")
    ap.add_argument(
        "--home",
        type=Path,
        help="a D5RL_HOME whose finished copies (verified first) are fingerprinted instead of generating "
        "them again in a temporary one; what is missing there is generated there",
    )
    args = ap.parse_args(argv)
    record(args.datasets or sorted(dataset_tasks()), args.out, args.workers, args.home)
    return 0


if __name__ == "__main__":
    sys.exit(main())
