"""The one executor of bench cells (d5rl.parallel.Tasks): each backend returns what a task returned, or why it
did not; the runner makes no Ray calls of its own."""

import ast
import os
import signal
from pathlib import Path

import pytest

from d5rl.parallel import Tasks

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
    with Tasks(workers) as tasks:
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
    with Tasks(1) as tasks:
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
