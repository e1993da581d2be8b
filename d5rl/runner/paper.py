"""The paper's published results (D5RL, Tables 1 and 2), for side-by-side comparison in reports.

Transcribed from the paper's LaTeX source (``../shared/seed``): mean and ± over its seeds, 500k
gradient steps (Table 2: 500k offline then 500k online), its own datasets and score references.
``None`` for the ± where the paper prints a bare number; an entry absent where it prints "-".
:func:`paper_repeats` finds the entries the paper prints twice, digit for digit (e.g. TD3+BC's and
RLPD's on A1 run), which the comparison tables mark.
Kitchen and WidowX in the paper are camera tasks; our ``-state`` twins compare against the same
row (see :func:`paper_task`), which the report says next to the table.
"""

from __future__ import annotations

import re

from d5rl.errors import D5RLError
from d5rl.registry import base_task
from d5rl.runner.results import method_name

_VERSION = re.compile(r"-v\d+$")

# {table: {task: {algo: (mean, std or None)}}}
PAPER: dict[str, dict[str, dict[str, tuple[float, float | None]]]] = {
    "offline": {  # Table 1
        "kitchen-standard-mixed-v0": {
            "bc": (0.461, 0.124),
            "iql": (0.457, 0.129),
            "cql": (0.0, 0.0),
            "calql": (0.0, 0.0),
            "td3bc": (0.003, 0.003),
            "rlpd": (0.0, 0.0),
            "ddpm_bc": (0.253, 0.082),
            "idql": (0.020, 0.008),
        },
        "kitchen-standard-partial-v0": {
            "bc": (0.474, 0.063),
            "iql": (0.427, 0.116),
            "cql": (0.0, 0.0),
            "calql": (0.0, 0.0),
            "td3bc": (0.053, 0.075),
            "rlpd": (0.0, 0.0),
            "ddpm_bc": (0.163, 0.054),
            "idql": (0.087, 0.021),
        },
        "kitchen-randomized-demos-v0": {
            "bc": (0.144, 0.010),
            "iql": (0.174, 0.031),
            "cql": (0.023, 0.032),
            "calql": (0.023, 0.016),
            "td3bc": (0.052, 0.033),
            "rlpd": (0.025, 0.036),
            "ddpm_bc": (0.126, 0.016),
            "idql": (0.033, 0.011),
        },
        "kitchen-randomized-mixed-v0": {
            "bc": (0.057, 0.019),
            "iql": (0.027, 0.0),
            "cql": (0.005, 0.002),
            "calql": (0.004, 0.001),
            "td3bc": (0.057, 0.026),
            "rlpd": (0.017, 0.024),
            "ddpm_bc": (0.105, 0.016),
            "idql": (0.009, 0.004),
        },
        "kitchen-randomized-partial-v0": {
            "bc": (0.072, 0.019),
            "iql": (0.048, 0.015),
            "cql": (0.003, 0.005),
            "calql": (0.001, 0.001),
            "td3bc": (0.023, 0.007),
            "rlpd": (0.008, 0.012),
            "ddpm_bc": (0.044, 0.010),
            "idql": (0.002, 0.001),
        },
        "a1-walk-v0": {
            "bc": (1.006, 0.015),
            "iql": (0.962, 0.007),
            "cql": (0.068, 0.112),
            "calql": (-0.171, 0.033),
            "td3bc": (0.549, 0.178),
            "rlpd": (0.032, 0.007),
        },
        "a1-run-v0": {
            "bc": (0.684, 0.026),
            "iql": (0.932, 0.006),
            "cql": (-0.067, 0.045),
            "calql": (-0.206, 0.086),
            "td3bc": (0.002, 0.021),
            "rlpd": (0.002, 0.021),
        },
        "a1-hiking-v0": {
            "bc": (0.956, 0.004),
            "iql": (0.935, 0.003),
            "cql": (0.0, 0.004),
            "calql": (-0.013, 0.008),
            "td3bc": (0.003, 0.001),
            "rlpd": (0.003, 0.001),
        },
        "wx-sorting-v0": {
            "bc": (0.152, 0.032),
            "iql": (0.021, 0.016),
            "cql": (0.0, 0.0),
            "calql": (0.0, 0.0),
            "td3bc": (0.016, 0.022),
            "ddpm_bc": (0.041, None),
            "idql": (0.173, None),
        },
        "wx-sorting-pickplacedata-v0": {
            "bc": (0.084, 0.048),
            "iql": (0.0, 0.0),
            "cql": (0.0, 0.0),
            "calql": (0.0, 0.0),
            "td3bc": (0.0, 0.0),
            "ddpm_bc": (0.081, None),
            "idql": (0.25, None),
        },
    },
    "online": {  # Table 2 (its randomized-kitchen CalQL, TD3+BC and IDQL entries repeat Table 1's)
        "kitchen-standard-mixed-v0": {
            "iql": (0.123, 0.102),
            "cql": (0.0, 0.0),
            "calql": (0.0, 0.0),
            "td3bc": (0.067, 0.066),
            "rlpd": (0.139, 0.075),
            "ddpm_bc": (0.200, 0.029),
            "idql": (0.020, 0.008),
        },
        "kitchen-standard-partial-v0": {
            "iql": (0.290, 0.064),
            "cql": (0.0, 0.0),
            "calql": (0.0, 0.0),
            "td3bc": (0.093, 0.059),
            "rlpd": (0.221, 0.113),
            "ddpm_bc": (0.177, 0.022),
            "idql": (0.087, 0.021),
        },
        "kitchen-randomized-demos-v0": {
            "iql": (0.234, 0.017),
            "cql": (0.0, 0.0),
            "calql": (0.023, 0.016),
            "td3bc": (0.052, 0.033),
            "rlpd": (0.001, 0.001),
            "ddpm_bc": (0.166, 0.029),
            "idql": (0.033, 0.011),
        },
        "kitchen-randomized-mixed-v0": {
            "iql": (0.25, 0.0),
            "cql": (0.0, 0.0),
            "calql": (0.004, 0.001),
            "td3bc": (0.057, 0.026),
            "rlpd": (0.011, 0.009),
            "ddpm_bc": (0.133, 0.004),
            "idql": (0.009, 0.004),
        },
        "kitchen-randomized-partial-v0": {
            "iql": (0.021, 0.009),
            "cql": (0.0, 0.0),
            "calql": (0.001, 0.001),
            "td3bc": (0.023, 0.007),
            "rlpd": (0.0, 0.0),
            "ddpm_bc": (0.084, 0.009),
            "idql": (0.002, 0.001),
        },
        "a1-walk-v0": {
            "iql": (0.935, 0.017),
            "cql": (0.068, 0.112),
            "calql": (0.750, 0.027),
            "td3bc": (0.030, 0.003),
            "rlpd": (1.016, 0.005),
        },
        "a1-run-v0": {
            "iql": (0.936, 0.021),
            "cql": (-0.067, 0.045),
            "calql": (0.700, 0.066),
            "td3bc": (0.110, 0.091),
            "rlpd": (1.011, 0.007),
        },
        "a1-hiking-v0": {
            "iql": (0.927, 0.014),
            "cql": (0.0, 0.004),
            "calql": (0.368, 0.107),
            "td3bc": (0.938, 0.015),
            "rlpd": (1.058, 0.020),
        },
    },
}


def paper_task(task: str) -> str:
    """The paper's row for one of our tasks: a ``-state`` twin maps to its camera task, a task on a
    dataset variant (the kitchen's imported human data) to the task it re-uses, and a later version of a
    task to version 0 (the paper's rows carry our version-0 ids; ``a1-walk-v1``, the authors' release's
    own definition of the paper's A1 walk, compares with the paper's walk row)."""
    try:
        task = base_task(task)
    except D5RLError:  # a task only a custom job knows
        pass
    task = task.replace("-state-v", "-v")
    first = _VERSION.sub("-v0", task)
    return first if any(first in rows for rows in PAPER.values()) else task


def same_task(a: str, b: str) -> bool:
    """Whether two task ids name one task in different versions (``a1-walk-v0``, ``a1-walk-v1``)."""
    return _VERSION.sub("", a) == _VERSION.sub("", b)


def paper_result(task: str, algo: str, phase: str) -> tuple[float, float | None] | None:
    """The paper's (mean, ±) for a (task, algorithm) in ``phase`` ('offline' or 'online'), or None."""
    return PAPER.get(phase, {}).get(paper_task(task), {}).get(algo)


def paper_methods(task: str, phase: str) -> set[str]:
    """The methods the paper reports for ``task`` in ``phase``."""
    return set(PAPER.get(phase, {}).get(paper_task(task), {}))


def paper_repeats(task: str, algo: str, phase: str) -> list[str]:
    """Where else the paper prints this entry's exact mean and ±: the other methods of the same row that
    share it, and, for a Table 2 entry, ``"offline"`` where it equals the same method's Table 1 entry.

    Zero entries (0.0 ± 0.0) and bare numbers are left out: agreeing there says nothing.  Two methods
    sharing a nonzero mean and ± to three decimals is unlikely by chance, so one of them is likely a
    transcription error; a Table 2 entry equal to Table 1's shows no change from online fine-tuning."""
    mine = paper_result(task, algo, phase)
    if mine is None or mine[1] is None or mine == (0.0, 0.0):
        return []
    row = PAPER.get(phase, {}).get(paper_task(task), {})
    out = [a for a, v in row.items() if a != algo and v == mine]
    if phase == "online" and paper_result(task, algo, "offline") == mine:
        out.append("offline")
    return out


def repeat_text(where: str) -> str:
    """One place of :func:`paper_repeats` in words: "RLPD's on this row", "its Table 1 entry"."""
    return "its Table 1 entry" if where == "offline" else f"{method_name(where)}'s on this row"
