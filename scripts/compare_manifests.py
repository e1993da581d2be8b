"""Compare the shard checksums of two manifests of one dataset (e.g. generated on two machines): `python scripts/compare_manifests.py MINE.json REFERENCE.json`."""
import json, sys
from pathlib import Path
mine = json.loads(Path(sys.argv[1]).read_text())
ref = json.loads(Path(sys.argv[2]).read_text())
same = diff = 0
first = None
for a, b in zip(mine["shards"], ref["shards"]):
    for k, v in b["arrays"].items():
        if a["arrays"].get(k, {}).get("sha256") == v["sha256"]:
            same += 1
        else:
            diff += 1
            first = first or k
print(f"determinism {mine['dataset']}: {len(mine['shards'])}/{len(ref['shards'])} shards, "
      f"{same} arrays byte-identical to the reference, {diff} differ (first: {first}); "
      f"transitions {mine['num_transitions']} vs {ref['num_transitions']}; packages here {mine.get('packages')}")
