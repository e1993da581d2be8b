import gymnasium
import pytest

import d5rl
from d5rl.errors import D5RLError, TaskIdError, UnknownTaskError
from d5rl.registry import TaskId, parse_task_id


@pytest.mark.parametrize(
    "tid,want",
    [
        ("a1-walk-v0", TaskId("a1", "walk", 0)),
        ("kitchen-standard-mixed-v0", TaskId("kitchen", "standard-mixed", 0)),
        ("wx-sorting-pickplacedata-v12", TaskId("wx", "sorting-pickplacedata", 12)),
    ],
)
def test_parse_task_id(tid, want):
    assert parse_task_id(tid) == want and str(want) == tid


@pytest.mark.parametrize("bad", ["a1-walk", "A1-walk-v0", "a1--walk-v0", "walk-v0", "", "a1-walk-vx", None])
def test_malformed_ids_are_rejected_with_a_hint(bad):
    with pytest.raises(TaskIdError) as e:
        parse_task_id(bad)
    assert "d5rl list" in str(e.value)


def test_unknown_task_suggests_close_ids():
    from tests.datasets.toy import register_toy

    register_toy("registry")
    with pytest.raises(UnknownTaskError, match="did you mean test-registry-v0"):
        d5rl.get_spec("test-registri-v0")


def test_every_registered_task_is_also_a_gymnasium_env():
    for tid in d5rl.list_tasks():
        assert f"d5rl/{tid}" in gymnasium.registry
        assert d5rl.get_spec(f"d5rl/{tid}").id == tid


def test_normalize_score_without_reference_explains():
    from tests.datasets.toy import register_toy

    register_toy("noscore")
    with pytest.raises(D5RLError, match="reference scores"):
        d5rl.normalize_score("test-noscore-v0", 1.0)
