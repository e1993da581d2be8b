"""Every D5RLError, whatever else it derives from (KeyError, OSError, ImportError, ...), reads as the same
one line: ``message (hint: hint)``.  The CLI prints exactly that after ``error: ``."""

import importlib
import inspect
import pkgutil

import numpy as np
import pytest

import d5rl
from d5rl.errors import D5RLError, is_int


def all_error_classes():
    for m in pkgutil.walk_packages(d5rl.__path__, "d5rl."):  # every module, so that every subclass is defined
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
    found, todo = {D5RLError}, [D5RLError]
    while todo:
        for sub in todo.pop().__subclasses__():
            if sub.__module__.startswith("d5rl.") and sub not in found:
                found.add(sub)
                todo.append(sub)
    return sorted(found, key=lambda c: f"{c.__module__}.{c.__qualname__}")


CLASSES = all_error_classes()


def test_found_them_all():
    names = {c.__name__ for c in CLASSES}
    assert {
        "UnknownTaskError",
        "ConfigError",
        "UnknownAgentError",
        "DatasetNotFoundError",
        "MissingDependencyError",
        "CorruptChunkError",
        "ResetNeededError",
    } <= names, names


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__qualname__)
def test_one_line(cls):
    takes_hint = "hint" in inspect.signature(cls).parameters
    e = cls("the dataset is stale", "run `d5rl generate`") if takes_hint else cls("the dataset is stale")
    assert e.message == "the dataset is stale"
    assert str(e) == "the dataset is stale" + (f" (hint: {e.hint})" if e.hint else "")
    if takes_hint:  # no quotes (KeyError), no errno (OSError), the hint after the message
        assert str(e) == "the dataset is stale (hint: run `d5rl generate`)"
        assert str(cls("no hint here")) == "no hint here"


@pytest.mark.parametrize(
    "value, lo, hi, ok",
    [
        (0, 0, None, True),
        (3, 1, 3, True),
        (np.int64(5), 1, None, True),
        (np.uint8(7), 0, 255, True),
        (-1, 0, None, False),
        (4, 1, 3, False),
        (0, 1, None, False),
        (True, 0, None, False),
        (np.bool_(True), 0, None, False),
        (2.0, 0, None, False),
        ("2", 0, None, False),
        (None, 0, None, False),
        (float("nan"), 0, None, False),
    ],
)
def test_is_int(value, lo, hi, ok):
    assert is_int(value, lo=lo, hi=hi) is ok
