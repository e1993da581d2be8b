"""The one executor (d5rl.parallel.Executor): each backend returns what a task returned, or why it
did not; the runner makes no Ray calls of its own."""

import ast
import os
import signal
from pathlib import Path

import pytest

from d5rl.parallel import Executor

RUNNER = Path(__file__).resolve().parents[2] / "d5rl" / "runner"


def square(x):
    return {"square": x * x, "pid": os.getpid()}


def fail(x):
    raise ValueError(f"no {x}")


def die(x):
    os.kill(os.getpid(), signal.SIGKILL)


@pytest.mark.parametrize("workers", [0, 2])
def test_tasks_return_values_and_errors(workers):
    finished = {}
    with Executor(workers, fresh=True) as tasks:
        for key, fn, x in (("a", "square", 3), ("b", "fail", 4), ("c", "square", 5)):
            while not tasks.free:
                finished.update({f.key: f for f in tasks.wait()})
            tasks.submit(key, f"{__name__}:{fn}", x)
        while tasks.running:
            finished.update({f.key: f for f in tasks.wait()})
    assert finished["a"].value["square"] == 9 and finished["c"].value["square"] == 25
    assert finished["b"].value is None and finished["b"].error == "ValueError: no 4"
    assert "raise ValueError" in finished["b"].traceback
    here = [finished[k].value["pid"] == os.getpid() for k in "ac"]
    assert here == [workers == 0] * 2  # in this process, or each in a fresh one
    if workers:
        assert finished["a"].value["pid"] != finished["c"].value["pid"]


def test_a_worker_that_dies_is_reported():
    with Executor(1, fresh=True) as tasks:
        tasks.submit("x", f"{__name__}:die", 0)
        [done] = tasks.wait()
    assert (done.key, done.value, done.error) == ("x", None, "worker process died (killed by signal 9)")


def test_the_runner_makes_no_ray_calls():
    """d5rl.runner reaches Ray only through d5rl.parallel: no module of it imports ray."""
    found = []
    for path in sorted(RUNNER.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            found += [f"{path.name}:{node.lineno}" for n in names if n == "ray" or n.startswith("ray.")]
    assert found == []


_STATE = {"inits": 0}


def init(tag):
    _STATE["inits"] += 1
    _STATE["tag"] = tag


def state_and_report(x):
    from d5rl.parallel import report

    report(x)
    return {"pid": os.getpid(), "inits": _STATE["inits"], "tag": _STATE.get("tag")}


@pytest.mark.parametrize("workers,fresh", [(0, False), (2, False), (2, True)])
def test_initializer_once_per_process_and_messages_reach_the_driver(workers, fresh):
    got, finished = [], []
    options = {"fresh": fresh, "initializer": init, "initargs": ("t",), "on_message": got.append}
    before = _STATE["inits"]
    with Executor(workers, **options) as tasks:
        for x in range(6):
            while not tasks.free:
                finished += tasks.wait()
            tasks.submit(x, state_and_report, x)
        while tasks.running:
            finished += tasks.wait()
    assert sorted(got) == list(range(6)) and sorted(f.key for f in finished) == list(range(6))
    values = [f.value for f in finished]
    assert {v["tag"] for v in values} == {"t"}
    pids = {v["pid"] for v in values}
    if workers == 0:
        assert pids == {os.getpid()} and _STATE["inits"] == before + 1
    elif fresh:
        assert len(pids) == 6 and {v["inits"] for v in values} == {1}  # one process per task
    else:
        assert 1 <= len(pids) <= 2 and os.getpid() not in pids  # long-lived workers, set up once each
        assert {v["inits"] for v in values} == {1}


def test_a_failed_task_leaves_its_long_lived_worker_serving():
    with Executor(1) as tasks:
        tasks.submit("bad", f"{__name__}:fail", 1)
        [bad] = tasks.wait()
        tasks.submit("good", f"{__name__}:square", 2)
        [good] = tasks.wait()
    assert isinstance(bad.exception, ValueError) and bad.error == "ValueError: no 1"
    assert good.value["square"] == 4
