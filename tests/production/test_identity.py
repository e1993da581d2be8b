"""Moving the code that makes a dataset does not change the dataset's identity."""

import json

from d5rl.datasets.generation import identity, producer_name
from d5rl.datasets.references import REFERENCES
from d5rl.registry import get_spec, list_tasks


def _datasets() -> dict:
    out = {}
    for task in list_tasks():
        spec = get_spec(task)
        if spec.dataset is not None:
            out[spec.dataset.name] = spec.dataset
    return out


def test_manifests_name_each_producer_as_the_committed_references_do():
    refs = json.loads(REFERENCES.read_text())
    datasets = _datasets()
    assert set(refs) <= set(datasets)
    assert {name: producer_name(datasets[name]) for name in refs} == {n: r["generator"] for n, r in refs.items()}


def test_moved_producers_keep_the_names_their_data_carry():
    toy = get_spec("toy-reach-v0").dataset
    assert identity(toy)["generator"] == "d5rl.envs.toy.data:ToyGenerator" != toy.generator
    assert producer_name(get_spec("kitchen-standard-mixed-human-v0").dataset) == (
        "d5rl.envs.kitchen.human:KitchenHumanImport"
    )
