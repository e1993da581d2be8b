"""Tables, aggregates and plots computed from a run directory's logs.

``d5rl report RUN_DIR`` writes to ``RUN_DIR/report/``:

* ``scores.csv`` — one row per finished cell: task, algorithm, seed, final
  offline / online normalized score (the raw data of everything below);
* ``table1_offline.{md,csv}`` — the layout of the paper's Table 1: rows are
  (environment, task), columns methods, entries mean ± std over seeds of the final
  offline score;
* ``table2_online.{md,csv}`` — Table 2, the same after online fine-tuning
  (cells run with ``online_steps > 0``);
* ``table1_offline_vs_paper.md``, ``table2_online_vs_paper.md`` — each entry next to the paper's
  (:mod:`d5rl.runner.paper`), for tasks the paper reports;
* ``aggregate.{md,csv}`` — per method and table: IQM over all tasks and seeds
  with a 95 % stratified-bootstrap interval (:mod:`d5rl.runner.stats`), and the mean;
* ``curves/<task>.png`` — learning curves (mean ± std over seeds per method);
* ``protocol.md`` — per task and method: steps, evaluation episodes, the dataset the cells trained on,
  and the wall time a cell took;
* ``report.md`` — all of it on one page, with links to rollout videos the trainer saved.

``±`` is the standard deviation over seeds with ``ddof=0`` (``numpy.std``).  Cells trained on data
their task no longer has (a newer dataset or generator version), or by another agent than the one their
command now gives (an older agent version, settings that resolve otherwise), are left out of every table
and listed as stale; ``d5rl bench`` with the same command trains them again.
"""

from __future__ import annotations

import csv
import dataclasses
import importlib.util
import io
import os
from pathlib import Path

import numpy as np

from d5rl.errors import D5RLError, is_int
from d5rl.runner import stats
from d5rl.runner.execute import attempt_header
from d5rl.runner.grid import find_cells, stale_reason, trained_on
from d5rl.runner.logs import final_scores, read_evals
from d5rl.training.rundir import RunDir

# Paper order and display names; algorithms outside this list follow in alphabetical order.
METHODS = {
    "bc": "BC",
    "iql": "IQL",
    "cql": "CQL",
    "calql": "CalQL",
    "td3bc": "TD3+BC",
    "rlpd": "RLPD",
    "ddpm_bc": "DDPM+BC",
    "idql": "IDQL",
    "fql": "FQL",
    "rebrac": "ReBRAC",
}
# (benchmark group, environment label) in the paper's row order.
ENVIRONMENTS = [
    ("kitchen-standard", "Standard Kitchen"),
    ("kitchen-randomized", "Randomized Kitchen"),
    ("a1", "Locomotion"),
    ("wx", "WidowX"),
]
VIDEO_EXTS = (".mp4", ".gif", ".webm")
VIDEOS_PER_CELL = 3
GRID_FOLDER = "cells"  # a published grid's cells live in docs/results/NAME/cells: the grid's name is NAME


class ReportError(D5RLError):
    """Nothing to report (no cells, or no finished cell with evaluations)."""


def environment(task: str) -> str:
    """The table's environment label of a task: its benchmark group (TaskSpec.group)."""
    try:
        from d5rl.settings import task_keys

        group, _ = task_keys(task)
    except D5RLError:  # a task only a custom job knows
        group = task.split("-")[0]
    return dict(ENVIRONMENTS).get(group, group)


def _env_order(label: str) -> int:
    labels = [lab for _, lab in ENVIRONMENTS]
    return labels.index(label) if label in labels else len(labels)


def task_order(task: str) -> tuple:
    """Sort key of a task in the tables: the paper's environment order, then the task id."""
    env = environment(task)
    return _env_order(env), env, task


def method_name(algo: str) -> str:
    return METHODS.get(algo, algo)


def method_order(algos) -> list[str]:
    known = [a for a in METHODS if a in algos]
    return known + sorted(a for a in algos if a not in METHODS)


@dataclasses.dataclass
class CellResult:
    task: str
    algo: str
    seed: int
    offline_steps: int
    online_steps: int
    directory: Path
    done: bool
    evals: list[dict]
    final: dict[str, float]
    failures: int
    videos: list[Path]
    stale: str | None = None  # why the result describes data the task no longer has (None: current)
    data: dict | None = None  # the dataset the job recorded (name, versions, seed, episodes)
    wall_s: float | None = None  # the run's wall time summed over the processes that ran it (a resumed run has several)
    wall_is_last_process: bool = False  # resumed by code that did not yet add up earlier processes: a lower bound
    eval_episodes: int | None = None  # episodes of the final evaluation
    stats: dict[str, float] | None = None  # the final evaluation's episode statistics (what the agent did)

    @property
    def counts(self) -> bool:
        """Finished on the task's current data: its scores go into the tables."""
        return self.done and self.stale is None

    @property
    def final_step(self) -> dict[str, int]:
        """The step of each phase's last evaluation."""
        out = {}
        for e in self.evals:
            out[e["phase"]] = e["step"]
        return out


def collect(run_dir: Path | str) -> list[CellResult]:
    """Every cell of a run directory with its evaluations (read from the cell's eval log)."""
    out = []
    for cell, cdir in find_cells(run_dir):
        rows = read_evals(cdir, cell.task, cell.offline_steps)
        final = final_scores(rows)
        if cell.online_steps <= 0:
            final.pop("online", None)
        videos = sorted(p for p in cdir.rglob("*") if p.suffix.lower() in VIDEO_EXTS)
        files = RunDir(cdir)
        done = files.is_done()
        marker = _read_json(files.done) if done else {}
        summary = marker.get("summary") or {}
        wall, partial = summary.get("run_wall_s"), False
        if wall is None and marker.get("wall_s") is not None:  # older runs: the last process's time only
            wall, partial = marker["wall_s"], _processes(files.log, cell.key) > 1
        out.append(
            CellResult(
                cell.task,
                cell.algo,
                cell.seed,
                cell.offline_steps,
                cell.online_steps,
                cdir,
                done,
                rows,
                final,
                len(files.read_failures()),
                videos,
                stale=stale_reason(cell, cdir) if done else None,
                data=trained_on(cdir),
                wall_s=wall,
                wall_is_last_process=partial,
                eval_episodes=summary.get("episodes"),
                stats=_read_json(files.summary).get("stats") if done else None,
            )
        )
    return out


def _processes(log: Path, key: str) -> int:
    """How many processes worked on a cell: the attempt headers in its log."""
    try:
        return sum(line.startswith(attempt_header(key)) for line in log.read_text(errors="replace").splitlines())
    except OSError:
        return 1


def _read_json(path: Path) -> dict:
    import json

    try:
        out = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return out if isinstance(out, dict) else {}


def table_cells(results: list[CellResult], phase: str) -> dict[tuple[str, str], list[CellResult]]:
    """``{(task, algo): cells}``: the finished cells on current data with a final score in ``phase``, the
    cells behind each entry of that phase's table."""
    out: dict[tuple[str, str], list[CellResult]] = {}
    for r in results:
        if r.counts and phase in r.final:
            out.setdefault((r.task, r.algo), []).append(r)
    return out


def score_table(results: list[CellResult], phase: str) -> dict[tuple[str, str], np.ndarray]:
    """``{(task, algo): final scores over seeds}`` of finished cells for one phase."""
    return {
        k: np.asarray([r.final[phase] for r in cells], np.float64) for k, cells in table_cells(results, phase).items()
    }


def seed_interval(scores, reps: int = 2000, seed: int = 0, confidence: float = 0.95) -> tuple[float, float]:
    """The percentile-bootstrap interval of the mean score over seeds (one stratum of
    :func:`d5rl.runner.stats.stratified_bootstrap_ci`); with one seed, that seed's score twice."""
    _, lo, hi = stats.stratified_bootstrap_ci(
        [np.asarray(scores, np.float64)], np.mean, reps=reps, confidence=confidence, rng=np.random.default_rng(seed)
    )
    return lo, hi


def _fmt(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}"


def _table_rows(table: dict, algos: list[str]):
    tasks = sorted({t for t, _ in table}, key=task_order)
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


def table_markdown(table: dict, title: str) -> str:
    algos = method_order({a for _, a in table})
    rows = _table_rows(table, algos)
    seeds = _most_seeds(rows)
    lines = _grid_markdown(algos, rows, lambda task, a, e: _entry(e, seeds))
    return "\n".join([f"### {title}", ""] + lines) + "\n"


def comparison_markdown(table: dict, phase: str, title: str) -> str | None:
    """Our table next to the paper's: each entry "ours / paper" (mean ± std), None if the paper has no row.

    Its columns are the methods run here and every method the paper reports for these rows, so a method
    not run yet shows as "- / the paper's number" rather than vanishing from the table.  A task the paper
    did not benchmark keeps its row, labelled so, its entries "ours / -": the table has every task of
    the grid, as the one without the paper's does."""
    from d5rl.runner.paper import paper_methods, paper_result, paper_task

    algos = method_order({a for _, a in table}.union(*(paper_methods(t, phase) for t, _ in table)))
    rows = _table_rows(table, algos)
    if not any(paper_methods(task, phase) for _, task, _ in rows):
        return None
    seeds = _most_seeds(rows)

    def cell(task, a, e):
        return f"{_entry(e, seeds)} / {paper_entry(paper_result(task, a, phase))}"

    def label(task):
        if not paper_methods(task, phase):
            return f"{task} (not in the paper)"
        return task if paper_task(task) == task else f"{task} (paper: {paper_task(task)})"

    intro = [
        f"### {title} (ours / paper)",
        "",
        "Each entry: this run's mean ± std over seeds / the paper's (500k steps per phase, its own data "
        "and score references; its kitchen and WidowX agents see cameras, so a `-state` task is compared "
        "with its camera task's row). `-`: not run here (yet), or not in the paper.",
        "",
    ]
    return "\n".join(intro + _grid_markdown(algos, rows, cell, label)) + "\n"


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


def behaviour_table(results: list[CellResult]) -> list[dict]:
    """What the agents did in their final evaluation, from the statistics their task reports per episode (the
    kitchen: which subtasks were done; WidowX: each object lifted, in its bin, in the other; A1: speed, falls):
    per task (paper order) a row per method with the mean of each statistic over the finished cells that
    recorded it (None where none did)."""
    groups: dict[str, dict[str, list[dict]]] = {}
    for r in results:
        if r.counts and r.stats:
            groups.setdefault(r.task, {}).setdefault(r.algo, []).append(r.stats)
    out = []
    for task in sorted(groups, key=task_order):
        by_algo = groups[task]
        keys = sorted(set().union(*(st for cells in by_algo.values() for st in cells)))
        rows = []
        for algo in method_order(by_algo):
            vals = {k: [st[k] for st in by_algo[algo] if k in st] for k in keys}
            rows.append(
                {
                    "algo": algo,
                    "method": method_name(algo),
                    "cells": len(by_algo[algo]),
                    "stats": {k: float(np.mean(v)) if v else None for k, v in vals.items()},
                }
            )
        out.append(
            {
                "task": task,
                "keys": keys,
                "labels": [k.removeprefix("subtask/").replace("_", " ") for k in keys],
                "rows": rows,
            }
        )
    return out


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


def aggregate(table: dict, reps: int = 2000, seed: int = 0) -> list[dict]:
    """Per method (overall and per environment): IQM with a 95 % stratified-bootstrap CI, and the mean."""
    out = []
    algos = method_order({a for _, a in table})
    envs = sorted({environment(t) for t, _ in table}, key=lambda e: (_env_order(e), e))
    for a in algos:
        groups = [("all", None)] + [(e, e) for e in envs] if len(envs) > 1 else [("all", None)]
        for label, env in groups:
            strata = [v for (t, aa), v in sorted(table.items()) if aa == a and (env is None or environment(t) == env)]
            if not strata:
                continue
            rng = np.random.default_rng(seed)
            point, lo, hi = stats.stratified_bootstrap_ci(strata, stats.iqm, reps=reps, rng=rng)
            pooled = np.concatenate(strata)
            out.append(
                {
                    "method": a,
                    "group": label,
                    "tasks": len(strata),
                    "runs": int(pooled.size),
                    "iqm": point,
                    "iqm_lo": lo,
                    "iqm_hi": hi,
                    "mean": float(pooled.mean()),
                }
            )
    return out


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


def mean_curves(cells: list[CellResult]) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per algorithm (paper order), over the cells' seeds: ``(steps, mean score, std score)`` at every
    evaluated step.  ``cells`` should be of one task."""
    out = {}
    for a in method_order({c.algo for c in cells}):
        per_step: dict[int, list[float]] = {}
        for c in cells:
            if c.algo != a:
                continue
            for e in c.evals:
                per_step.setdefault(e["step"], []).append(e["score"])
        steps = np.array(sorted(per_step))
        out[a] = (
            steps,
            np.array([np.mean(per_step[s]) for s in steps]),
            np.array([np.std(per_step[s]) for s in steps]),
        )
    return out


def plot_curves(results: list[CellResult], out_dir: Path) -> list[Path]:
    """One PNG per task: normalized score against gradient steps, mean ± std over seeds per method."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    by_task: dict[str, list[CellResult]] = {}
    for r in results:
        if r.evals:
            by_task.setdefault(r.task, []).append(r)
    for task, cells in sorted(by_task.items()):
        fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
        for a, (steps, mean, std) in mean_curves(cells).items():
            (line,) = ax.plot(steps, mean, label=method_name(a), marker="." if len(steps) < 30 else None)
            ax.fill_between(steps, mean - std, mean + std, alpha=0.2, color=line.get_color())
        offline = {c.offline_steps for c in cells if c.online_steps > 0}
        for s in offline:
            ax.axvline(s, color="k", ls="--", lw=0.8)
        ax.set_title(task)
        ax.set_xlabel("steps (offline updates, then online env steps)")
        ax.set_ylabel("normalized score")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out_dir / f"{task}.png"
        fig.savefig(path)
        plt.close(fig)
        paths.append(path)
    return paths


def write_report(
    run_dir: Path | str,
    out_dir: Path | str | None = None,
    reps: int = 2000,
    seed: int = 0,
    plots: bool = True,
    videos: bool = False,
) -> Path:
    """Write every report file; returns the path of ``report.md``.  ``videos``: also render one rollout GIF
    per task from the best cell's checkpoint (:mod:`d5rl.runner.videos`)."""
    run_dir = Path(run_dir)
    for name, v, least, default in (("reps", reps, 1, 2000), ("seed", seed, 0, 0)):
        if not is_int(v, lo=least):
            raise ReportError(
                f"--{name} must be an integer >= {least}, got {v!r}", f"omit --{name} for its default ({default})"
            )
    if not run_dir.is_dir():
        raise ReportError(f"{run_dir} is not a directory", "pass the --out directory of `d5rl bench`")
    results = collect(run_dir)
    if not results:
        raise ReportError(f"no benchmark cells under {run_dir}", "run `d5rl bench --out RUN_DIR ...` first")
    if not any(r.counts and r.final for r in results):
        stale = [r for r in results if r.done and r.stale is not None]
        if stale:
            raise ReportError(
                f"every finished cell under {run_dir} is stale ({len(stale)}; e.g. {stale[0].task}/"
                f"{stale[0].algo}/seed{stale[0].seed}: {stale[0].stale}), so no table would have an entry",
                "train them again with the grid's `d5rl bench` command (add --dry-run to list them first)",
            )
        raise ReportError(
            f"no finished cell under {run_dir} has evaluations",
            "check the cells' log.txt / error.txt, then resume with the same `d5rl bench` command",
        )
    out = Path(out_dir) if out_dir else run_dir / "report"
    out.mkdir(parents=True, exist_ok=True)

    with open(out / "scores.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
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
            ]
        )
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

    run_name = run_dir.parent.name if run_dir.name == GRID_FOLDER else run_dir.name
    stale = [r for r in results if r.done and r.stale is not None]
    parts = [
        f"# Benchmark report: {run_name}",
        "",
        f"{sum(r.counts for r in results)} of {len(results)} cells finished"
        f"{f' ({len(stale)} more on older data or agents: see Stale cells)' if stale else ''}. "
        "Scores are normalized "
        "(0 = random, 1 = expert reference of the task); each cell's score is its last evaluation "
        "of the phase. ± is the standard deviation over seeds (ddof=0).",
        "",
    ]
    agg_rows = []
    for phase, name, title in (
        ("offline", "table1_offline", "Table 1: offline"),
        ("online", "table2_online", "Table 2: offline-to-online"),
    ):
        table = score_table(results, phase)
        if not table:
            continue
        md = table_markdown(table, title)
        (out / f"{name}.md").write_text(md)
        (out / f"{name}.csv").write_text(table_csv(table))
        agg = aggregate(table, reps=reps, seed=seed)
        agg_rows += aggregate_csv(agg, name)
        parts += [md, aggregate_markdown(agg, f"Aggregate ({title.split(': ')[1]})", reps)]
        vs = comparison_markdown(table, phase, title)
        if vs:
            (out / f"{name}_vs_paper.md").write_text(vs)
            parts.append(vs)
    with open(out / "aggregate.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["table", "method", "group", "tasks", "runs", "iqm", "iqm_lo", "iqm_hi", "mean"])
        w.writerows(agg_rows)
    (out / "aggregate.md").write_text("\n".join(p for p in parts if p.startswith("### Aggregate")))
    protocol = protocol_markdown(results)
    if protocol:
        (out / "protocol.md").write_text(protocol)
        parts.append(protocol)
    behaviour = behaviour_markdown(results)
    if behaviour:
        (out / "behaviour.md").write_text(behaviour)
        parts.append(behaviour)

    if plots:
        pngs = plot_curves(results, out / "curves")
        if not pngs and importlib.util.find_spec("matplotlib") is None:
            parts += ["## Learning curves", "", "Not drawn: matplotlib is not installed (pip install matplotlib).", ""]
        if pngs:
            parts += ["## Learning curves", ""]
            parts += [f"![{p.stem}]({os.path.relpath(p, out)})" for p in pngs]
            parts.append("")

    if videos:
        from d5rl.runner.videos import write_rollout_gifs

        write_rollout_gifs(results, out)
    from d5rl.runner.videos import read_captions

    gifs = {t: c for t, c in sorted(read_captions(out / "videos").items()) if (out / "videos" / f"{t}.gif").exists()}
    if gifs:
        parts += [
            "## Rollouts",
            "",
            "One evaluation episode per task of its best cell's final policy (`d5rl report RUN_DIR --videos`).",
            "",
        ]
        for task, caption in gifs.items():
            parts += [f"**{task}**: {caption}", "", f"![{task}](videos/{task}.gif)", ""]

    early = [
        r
        for r in results
        if r.done and r.online_steps > 0 and r.final_step.get("offline", r.offline_steps) != r.offline_steps
    ]
    if early:
        parts += [
            "## Caveats",
            "",
            "These cells have no evaluation exactly at the end of the offline phase; their "
            "Table 1 entry uses their last offline evaluation (step in scores.csv). Choose an evaluation "
            "interval that divides --offline-steps to avoid this.",
            "",
        ]
        parts += [
            f"- {r.task}/{r.algo}/seed{r.seed}: offline score from step {r.final_step.get('offline')} "
            f"of {r.offline_steps}"
            for r in early
        ] + [""]
    if stale:
        parts += [
            "## Stale cells",
            "",
            "Trained on data their task no longer has, or by an older version or other "
            "settings of their agent, so left out of every table above. The same `d5rl bench` command trains "
            "them again.",
            "",
            "| Cell | Why |",
            "|---|---|",
        ]
        parts += [f"| {r.task}/{r.algo}/seed{r.seed} | {r.stale} |" for r in stale] + [""]
    incomplete = [r for r in results if not r.done]
    if incomplete:
        parts += ["## Unfinished cells", "", "| Cell | Failed attempts | Error |", "|---|---|---|"]
        for r in incomplete:
            err = RunDir(r.directory).error
            link = f"[{err.name}]({os.path.relpath(err, out)})" if err.exists() else "not run yet / running"
            parts.append(f"| {r.task}/{r.algo}/seed{r.seed} | {r.failures} | {link} |")
        parts.append("")
    videos = [(r, v) for r in results for v in r.videos[-VIDEOS_PER_CELL:]]  # the latest (final policy) videos
    if videos:
        parts += ["## Rollout videos", ""]
        for r, v in videos:
            parts.append(f"- {r.task} / {method_name(r.algo)} / seed {r.seed}: [{v.name}]({os.path.relpath(v, out)})")
        parts.append("")
    path = out / "report.md"
    path.write_text("\n".join(parts))
    return path
