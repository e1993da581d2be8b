"""The toy datasets' producer: its score references."""

import d5rl
from d5rl.production.toy.data import reference_returns


def test_score_references_are_what_the_policies_score():
    spec = d5rl.get_spec("toy-reach-v0")
    assert (spec.score.random, spec.score.expert) == reference_returns()
