"""The report's Markdown and CSV renderings of a grid's results (:mod:`d5rl.runner.results`): the paper's
tables, the comparison with the paper's numbers, aggregates, the protocol and cost table and what the agents did.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from d5rl.runner.paper import paper_methods, paper_repeats, paper_result, paper_task, same_task
from d5rl.runner.results import (
    CellResult,
    behaviour_table,
    environment,
    method_name,
    method_order,
    task_order,
)


def _fmt(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}"


def _table_rows(table: dict, algos: list[str], tasks=()):
    """One row per task of ``table`` and of ``tasks`` (a task whose cells are all stale keeps its row, "-")."""
    tasks = sorted({t for t, _ in table} | set(tasks), key=task_order)
    rows = []
    for task in tasks:
        entries = {}
        for a in algos:
            v = table.get((task, a))
            entries[a] = None if v is None else (float(v.mean()), float(v.std()), int(v.size))
        rows.append((environment(task), task, entries))
    return rows


def _most_seeds(rows) -> int:
    """The largest number of seeds behind any entry of a table."""
    return max((e[2] for _, _, entries in rows for e in entries.values() if e is not None), default=0)


def mean_std(mean: float, std: float) -> str:
    """How every table writes a mean over seeds and its standard deviation: "0.936 ± 0.002"."""
    return f"{_fmt(mean)} ± {_fmt(std)}"


def _entry(e, seeds: int) -> str:
    """One table entry: "mean ± std", "(n=k)" added where fewer seeds stand behind it than behind the
    table's fullest entry (a grid not yet finished), "-" where none."""
    if e is None:
        return "-"
    return mean_std(e[0], e[1]) + (f" (n={e[2]})" if e[2] < seeds else "")


def interval(lo: float, hi: float) -> str:
    """How every table writes a confidence interval: "[0.500, 0.700]"."""
    return f"[{_fmt(lo)}, {_fmt(hi)}]"


def paper_entry(p: tuple[float, float | None] | None) -> str:
    """The paper's (mean, ±) as the comparison tables write it: "-" where the paper has no entry, the bare
    mean where it prints no ±."""
    if p is None:
        return "-"
    return _fmt(p[0]) if p[1] is None else mean_std(*p)


def _grid_markdown(algos: list[str], rows, cell, label=lambda task: task) -> list[str]:
    """The header and the environment-grouped rows of a task x method table; ``cell(task, algo, entry)``
    writes one entry, ``label(task)`` one task's name."""
    lines = [
        "| Environment | Task | " + " | ".join(method_name(a) for a in algos) + " |",
        "|---|---|" + "---|" * len(algos),
    ]
    prev = None
    for env, task, entries in rows:
        cells = " | ".join(cell(task, a, entries[a]) for a in algos)
        lines.append(f"| {env if env != prev else ''} | {label(task)} | {cells} |")
        prev = env
    return lines


def table_markdown(table: dict, title: str, tasks=()) -> str:
    algos = method_order({a for _, a in table})
    rows = _table_rows(table, algos, tasks)
    seeds = _most_seeds(rows)
    lines = _grid_markdown(algos, rows, lambda task, a, e: _entry(e, seeds))
    return "\n".join([f"### {title}", ""] + lines) + "\n"


_LATER_VERSION = (
    " A later version of a task (A1 v1, the authors' release's definition) is compared with the paper's row."
)


def comparison_markdown(table: dict, phase: str, title: str, tasks=()) -> str | None:
    """Our table next to the paper's: each entry "ours / paper" (mean ± std), None if the paper has no row.

    Its columns are the methods run here and every method the paper reports for these rows, so a method
    not run yet shows as "- / the paper's number" rather than vanishing from the table.  A task the paper
    did not benchmark keeps its row, labelled so, its entries "ours / -", and so does a task of ``tasks``
    whose cells are all stale ("- / the paper's"): the table has every task of the grid, as the one without
    the paper's does."""

    every = {t for t, _ in table} | set(tasks)
    algos = method_order({a for _, a in table}.union(*(paper_methods(t, phase) for t in every)))
    rows = _table_rows(table, algos, tasks)
    if not any(paper_methods(task, phase) for _, task, _ in rows):
        return None
    seeds = _most_seeds(rows)

    repeats = {}  # the paper's entries it prints twice: marked, and listed under the table

    def cell(task, a, e):
        mark = ""
        if twice := paper_repeats(task, a, phase):
            repeats[(paper_task(task), a)] = twice
            mark = "†"
        return f"{_entry(e, seeds)} / {paper_entry(paper_result(task, a, phase))}{mark}"

    def label(task):
        if not paper_methods(task, phase):
            return f"{task} (not in the paper)"
        return task if same_task(paper_task(task), task) else f"{task} (paper: {paper_task(task)})"

    intro = [
        f"### {title} (ours / paper)",
        "",
        "Each entry: this run's mean ± std over seeds / the paper's (500k steps per phase, its own data "
        "and score references; its kitchen and WidowX agents see cameras, so a `-state` task is compared "
        "with its camera task's row). `-`: not run here (yet), or not in the paper."
        + _LATER_VERSION
        * any(paper_task(t) != t and same_task(paper_task(t), t) for _, t, _ in rows),
        "",
    ]
    lines = _grid_markdown(algos, rows, cell, label)
    if repeats:
        lines += ["", _repeat_footnote(repeats)]
    return "\n".join(intro + lines) + "\n"


def _repeat_footnote(repeats: dict) -> str:
    """The note under a comparison table on the paper's entries marked †, ``{(paper task, algo): where
    else the paper prints them}`` (:func:`d5rl.runner.paper.paper_repeats`)."""

    def listed(names):
        names = list(dict.fromkeys(names))
        return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]

    shared, as_offline = {}, {}
    for (task, a), where in sorted(repeats.items()):
        if "offline" in where:
            as_offline.setdefault(method_name(a), []).append(task)
        others = [w for w in where if w != "offline"]
        if others:
            methods = listed([method_name(m) for m in method_order({a, *others})])
            shared.setdefault(methods, []).append(task)

    parts = [
        f"The paper's {methods} entries on {listed(tasks)} are the same, mean and ± to three decimals: likely a "
        "transcription error in the paper, so compare with care."
        for methods, tasks in shared.items()
    ] + [
        f"The paper's Table 2 {m} entries on {listed(tasks)} are its Table 1 entries: it reports no change from "
        "online fine-tuning."
        for m, tasks in as_offline.items()
    ]
    return "† " + " ".join(parts)


def _data_label(data: dict | None) -> str:
    if not data:
        return "not recorded"
    eps = f", {data['episodes']} episodes" if data.get("episodes") is not None else ""
    return f"{data.get('dataset')} v{data.get('dataset_version')} ({data.get('generator_version')}){eps}"


def _duration(seconds: float) -> str:
    return (
        f"{seconds:.0f} s"
        if seconds < 120
        else (f"{seconds / 60:.1f} min" if seconds < 7200 else f"{seconds / 3600:.1f} h")
    )


def steps_label(cells: list[CellResult]) -> str:
    """The budgets of some cells: "20,000 + 10,000 online", several joined by commas."""
    return ", ".join(
        f"{off:,}" + (f" + {on:,} online" if on else "")
        for off, on in sorted({(c.offline_steps, c.online_steps) for c in cells})
    )


def protocol_markdown(results: list[CellResult]) -> str | None:
    """Per task and method, over the cells that count: budget, evaluation, data and wall time."""
    groups: dict[tuple[str, str], list[CellResult]] = {}
    for r in results:
        if r.counts:
            groups.setdefault((r.task, r.algo), []).append(r)
    if not groups:
        return None
    order = method_order({a for _, a in groups})
    keys = sorted(groups, key=lambda k: (*task_order(k[0]), order.index(k[1])))
    lines = [
        "### Protocol and cost",
        "",
        "Per task and method, over the finished cells: gradient steps (then online environment steps), "
        "episodes of the final evaluation, the dataset the cells trained on, and the median wall time of a "
        "cell summed over the processes that ran it (a cell resumed after a stop has several; its host and the "
        "others running beside it vary; see each cell's `done`; '>=': some cells were resumed before runs added "
        "up their processes' times, so only the last one's is known).",
        "",
        "| Task | Method | Cells | Steps | Final evaluation | Dataset | Wall time per cell |",
        "|---|---|---|---|---|---|---|",
    ]
    for task, algo in keys:
        cells = groups[(task, algo)]
        steps = steps_label(cells)
        eps = ", ".join(str(e) for e in sorted({int(c.eval_episodes) for c in cells if c.eval_episodes}))
        data = "; ".join(sorted({_data_label(c.data) for c in cells}))
        walls = [c.wall_s for c in cells if c.wall_s is not None]
        wall = _duration(float(np.median(walls))) if walls else "-"
        if walls and any(c.wall_is_last_process for c in cells):
            wall = ">= " + wall
        lines.append(
            f"| {task} | {method_name(algo)} | {len(cells)} | {steps} | "
            f"{eps + ' episodes' if eps else '-'} | {data} | {wall} |"
        )
    return "\n".join(lines) + "\n"


BEHAVIOUR_NOTE = (
    "Per task, what the final evaluation's episodes did, from the statistics the task reports per episode, "
    "averaged over episodes and then over the cells that recorded them (cells trained by older d5rl versions did not). "
    "Kitchen: the fraction of episodes in which each subtask's object reached its goal configuration, counted by "
    "the task or not; WidowX: the object was lifted off the table, ends in its bin, ends in the other bin; A1: "
    "mean forward speed (m/s), episodes that ended early (a fall, or off the course), waypoints reached."
)


def behaviour_markdown(results: list[CellResult]) -> str | None:
    """:func:`behaviour_table` as Markdown, or None when no cell recorded statistics."""
    tables = behaviour_table(results)
    if not tables:
        return None
    lines = ["### What the agents do", "", BEHAVIOUR_NOTE, ""]
    for t in tables:
        lines += [
            f"**{t['task']}**",
            "",
            "| Method | Cells | " + " | ".join(t["labels"]) + " |",
            "|---|---|" + "---|" * len(t["keys"]),
        ]
        for row in t["rows"]:
            vals = [row["stats"][k] for k in t["keys"]]
            lines.append(
                f"| {row['method']} | {row['cells']} | "
                + " | ".join("-" if v is None else _fmt(v, 2) for v in vals)
                + " |"
            )
        lines.append("")
    return "\n".join(lines)


def table_csv(table: dict) -> str:
    algos = method_order({a for _, a in table})
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["environment", "task"] + [f"{a}_{s}" for a in algos for s in ("mean", "std", "n")])
    for env, task, entries in _table_rows(table, algos):
        row = [env, task]
        for a in algos:
            e = entries[a]
            row += ["", "", 0] if e is None else [repr(e[0]), repr(e[1]), e[2]]
        w.writerow(row)
    return buf.getvalue()


def aggregate_markdown(rows: list[dict], title: str, reps: int) -> str:
    lines = [
        f"### {title}",
        "",
        f"IQM of normalized scores pooled over tasks and seeds, 95 % stratified-bootstrap CI ({reps} resamples).",
        "",
        "| Method | Group | Tasks | Runs | IQM | 95 % CI | Mean |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {method_name(r['method'])} | {r['group']} | {r['tasks']} | {r['runs']} | {_fmt(r['iqm'])} "
            f"| {interval(r['iqm_lo'], r['iqm_hi'])} | {_fmt(r['mean'])} |"
        )
    return "\n".join(lines) + "\n"


def aggregate_csv(rows: list[dict], table_name: str) -> list[list]:
    return [
        [
            table_name,
            r["method"],
            r["group"],
            r["tasks"],
            r["runs"],
            repr(r["iqm"]),
            repr(r["iqm_lo"]),
            repr(r["iqm_hi"]),
            repr(r["mean"]),
        ]
        for r in rows
    ]


SCORES_COLUMNS = (
    "environment",
    "task",
    "algo",
    "seed",
    "done",
    "offline_steps",
    "online_steps",
    "offline_score",
    "offline_score_step",
    "online_score",
    "online_score_step",
    "evaluations",
    "failed_attempts",
    "stale",
)


def scores_csv(results: list[CellResult]) -> str:
    """One row per cell (finished or not): its final score and the step of each phase's last evaluation."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(SCORES_COLUMNS)
    for r in sorted(results, key=lambda r: (r.task, r.algo, r.seed)):
        w.writerow(
            [
                environment(r.task),
                r.task,
                r.algo,
                r.seed,
                int(r.done),
                r.offline_steps,
                r.online_steps,
                repr(r.final["offline"]) if "offline" in r.final else "",
                r.final_step.get("offline", ""),
                repr(r.final["online"]) if "online" in r.final else "",
                r.final_step.get("online", ""),
                len(r.evals),
                r.failures,
                r.stale or "",
            ]
        )
    return buf.getvalue()


def aggregate_table_csv(rows: list[list]) -> str:
    """``aggregate.csv``: the rows of :func:`aggregate_csv` of every table under one header."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["table", "method", "group", "tasks", "runs", "iqm", "iqm_lo", "iqm_hi", "mean"])
    w.writerows(rows)
    return buf.getvalue()
