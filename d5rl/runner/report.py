"""``d5rl report``: a grid's report files and its page, assembled from the grid's results
(:mod:`d5rl.runner.results`) and their renderings (:mod:`d5rl.runner.tables`, :mod:`d5rl.runner.plots`,
:mod:`d5rl.runner.videos`).

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

import importlib.util
import os
from collections.abc import Collection
from pathlib import Path

from d5rl.errors import is_int
from d5rl.runner.plots import plot_curves
from d5rl.runner.results import (
    GRID_FOLDER,
    VIDEOS_PER_CELL,
    CellResult,
    ReportError,
    aggregate,
    collect,
    method_name,
    score_table,
)
from d5rl.runner.tables import (
    aggregate_csv,
    aggregate_markdown,
    aggregate_table_csv,
    behaviour_markdown,
    comparison_markdown,
    protocol_markdown,
    scores_csv,
    table_csv,
    table_markdown,
)
from d5rl.runner.videos import GIFS, caption_note, drop_rollouts, read_captions
from d5rl.training.rundir import RunDir


def write_report(
    run_dir: Path | str,
    out_dir: Path | str | None = None,
    reps: int = 2000,
    seed: int = 0,
    plots: bool = True,
    videos: bool | Collection[str] = False,
) -> Path:
    """Write every report file; returns the path of ``report.md``.  ``videos``: also render one rollout GIF
    per task from the best cell's checkpoint (:mod:`d5rl.runner.videos`): for every task (True) or for the
    tasks named."""
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
    filmed = _filmed(results, videos, run_dir)
    out = Path(out_dir) if out_dir else run_dir / "report"
    out.mkdir(parents=True, exist_ok=True)

    (out / "scores.csv").write_text(scores_csv(results))
    parts = _header(run_dir, results)
    parts += _tables(results, out, reps, seed)
    for name, md in (("protocol", protocol_markdown(results)), ("behaviour", behaviour_markdown(results))):
        if md:
            (out / f"{name}.md").write_text(md)
            parts.append(md)
    if plots:
        parts += _curves(results, out)
    if filmed:
        from d5rl.runner.videos import write_rollout_gifs  # JAX (the train extra): only for --videos

        write_rollout_gifs([r for r in results if r.task in filmed], out)
    drop_rollouts(out / GIFS, {r.task for r in results})
    parts += (
        _rollouts(out, results)
        + _caveats(results)
        + _stale(results)
        + _unfinished(results, out)
        + _videos(results, out)
    )
    path = out / "report.md"
    path.write_text("\n".join(parts))
    return path


def _header(run_dir: Path, results: list[CellResult]) -> list[str]:
    run_name = run_dir.parent.name if run_dir.name == GRID_FOLDER else run_dir.name
    stale = [r for r in results if r.done and r.stale is not None]
    return [
        f"# Benchmark report: {run_name}",
        "",
        f"{sum(r.counts for r in results)} of {len(results)} cells finished"
        f"{f' ({len(stale)} more on older data or agents: see Stale cells)' if stale else ''}. "
        "Scores are normalized "
        "(0 = random, 1 = expert reference of the task); each cell's score is its last evaluation "
        "of the phase. ± is the standard deviation over seeds (ddof=0).",
        "",
    ]


def _tables(results: list[CellResult], out: Path, reps: int, seed: int) -> list[str]:
    """Tables 1 and 2, their aggregates and the comparisons with the paper: written to their files, and
    the page's part."""
    parts, agg_rows = [], []
    for phase, name, title in (
        ("offline", "table1_offline", "Table 1: offline"),
        ("online", "table2_online", "Table 2: offline-to-online"),
    ):
        table = score_table(results, phase)
        if not table:
            continue
        tasks = {r.task for r in results if r.done and phase in r.final}  # with the stale ones: every row
        md = table_markdown(table, title, tasks)
        (out / f"{name}.md").write_text(md)
        (out / f"{name}.csv").write_text(table_csv(table))
        agg = aggregate(table, reps=reps, seed=seed)
        agg_rows += aggregate_csv(agg, name)
        parts += [md, aggregate_markdown(agg, f"Aggregate ({title.split(': ')[1]})", reps)]
        vs = comparison_markdown(table, phase, title, tasks)
        if vs:
            (out / f"{name}_vs_paper.md").write_text(vs)
            parts.append(vs)
    (out / "aggregate.csv").write_text(aggregate_table_csv(agg_rows))
    (out / "aggregate.md").write_text("\n".join(p for p in parts if p.startswith("### Aggregate")))
    return parts


def _curves(results: list[CellResult], out: Path) -> list[str]:
    pngs = plot_curves(results, out / "curves")
    if not pngs and importlib.util.find_spec("matplotlib") is None:
        return ["## Learning curves", "", "Not drawn: matplotlib is not installed (pip install matplotlib).", ""]
    if not pngs:
        return []
    return ["## Learning curves", "", *(f"![{p.stem}]({os.path.relpath(p, out)})" for p in pngs), ""]


def _filmed(results: list[CellResult], videos: bool | Collection[str], run_dir: Path) -> set[str]:
    """The tasks ``videos`` asks GIFs for: all of the grid's (True), none (False) or those named, each of which
    the grid must have."""
    tasks = {r.task for r in results}
    if isinstance(videos, bool):
        return tasks if videos else set()
    missing = sorted(set(videos) - tasks)
    if missing:
        raise ReportError(
            f"no cells of {', '.join(missing)} under {run_dir}", f"name tasks of the grid: {', '.join(sorted(tasks))}"
        )
    return set(videos)


def _rollouts(out: Path, results: list[CellResult]) -> list[str]:
    """The rollout GIFs in the report's folder (``--videos`` now or earlier), with their captions, each marked
    where the grid's results have moved on since it was made (:func:`d5rl.runner.videos.caption_note`)."""
    gifs = {t: c for t, c in sorted(read_captions(out / GIFS).items()) if (out / GIFS / f"{t}.gif").exists()}
    if not gifs:
        return []
    parts = [
        "## Rollouts",
        "",
        "One evaluation episode per task of its best cell's final policy (`d5rl report RUN_DIR --videos`).",
        "",
    ]
    for task, caption in gifs.items():
        note = caption_note(results, task, caption)
        caption = f"{caption} (**{note}**)" if note else caption
        parts += [f"**{task}**: {caption}", "", f"![{task}]({GIFS}/{task}.gif)", ""]
    return parts


def _caveats(results: list[CellResult]) -> list[str]:
    early = [
        r
        for r in results
        if r.done and r.online_steps > 0 and r.final_step.get("offline", r.offline_steps) != r.offline_steps
    ]
    if not early:
        return []
    parts = [
        "## Caveats",
        "",
        "These cells have no evaluation exactly at the end of the offline phase; their "
        "Table 1 entry uses their last offline evaluation (step in scores.csv). Choose an evaluation "
        "interval that divides --offline-steps to avoid this.",
        "",
    ]
    parts += [
        f"- {r.task}/{r.algo}/seed{r.seed}: offline score from step {r.final_step.get('offline')} of {r.offline_steps}"
        for r in early
    ]
    return parts + [""]


def _stale(results: list[CellResult]) -> list[str]:
    stale = [r for r in results if r.done and r.stale is not None]
    if not stale:
        return []
    parts = [
        "## Stale cells",
        "",
        "Trained on data their task no longer has, or by an older version or other "
        "settings of their agent, so left out of every table above. The same `d5rl bench` command trains "
        "them again.",
        "",
        "| Cell | Why |",
        "|---|---|",
    ]
    return parts + [f"| {r.task}/{r.algo}/seed{r.seed} | {r.stale} |" for r in stale] + [""]


def _unfinished(results: list[CellResult], out: Path) -> list[str]:
    incomplete = [r for r in results if not r.done]
    if not incomplete:
        return []
    parts = ["## Unfinished cells", "", "| Cell | Failed attempts | Error |", "|---|---|---|"]
    for r in incomplete:
        err = RunDir(r.directory).error
        link = f"[{err.name}]({os.path.relpath(err, out)})" if err.exists() else "not run yet / running"
        parts.append(f"| {r.task}/{r.algo}/seed{r.seed} | {r.failures} | {link} |")
    return parts + [""]


def _videos(results: list[CellResult], out: Path) -> list[str]:
    """Links to the evaluation videos the trainer saved: each cell's latest (its final policy's)."""
    videos = [(r, v) for r in results for v in r.videos[-VIDEOS_PER_CELL:]]
    if not videos:
        return []
    parts = ["## Rollout videos", ""]
    for r, v in videos:
        parts.append(f"- {r.task} / {method_name(r.algo)} / seed {r.seed}: [{v.name}]({os.path.relpath(v, out)})")
    return parts + [""]
