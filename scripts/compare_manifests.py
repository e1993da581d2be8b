"""Compare the array checksums of two manifests of one dataset, e.g. generated on two machines.

    python scripts/compare_manifests.py MINE/manifest.json REFERENCE/manifest.json

Prints how many arrays are byte-identical, which shards differ, and each side's package versions
(docs/guarantees.md, "Determinism, and its limit"). `d5rl verify TASK --reference` compares a dataset with
the committed reference instead.
"""

from __future__ import annotations

import sys
from pathlib import Path

from d5rl.datasets.format import read_manifest


def compare(mine: dict, ref: dict) -> str:
    same, differing, first = 0, [], None
    for i, (a, b) in enumerate(zip(mine["shards"], ref["shards"])):
        bad = [k for k, v in b["arrays"].items() if a["arrays"].get(k, {}).get("sha256") != v["sha256"]]
        same += len(b["arrays"]) - len(bad)
        if bad:
            differing.append(i)
            first = first or bad[0]
    return (
        f"{mine['dataset']}: {len(mine['shards'])}/{len(ref['shards'])} shards compared, {same} arrays "
        f"byte-identical, shards with differences {differing or 'none'} (first array: {first}); "
        f"transitions {mine['num_transitions']} vs {ref['num_transitions']}; "
        f"packages {mine.get('packages')} vs {ref.get('packages')}"
    )


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    print(compare(*(read_manifest(Path(p)) for p in sys.argv[1:])))
