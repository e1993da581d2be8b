"""The report's learning-curve plots (matplotlib, an optional dependency: without it there are none)."""

from __future__ import annotations

from pathlib import Path

from d5rl.runner.results import CellResult, mean_curves, method_name


def plot_curves(results: list[CellResult], out_dir: Path) -> list[Path]:
    """One PNG per task: normalized score against gradient steps, mean ± std over seeds per method; the PNGs
    of tasks without evaluated cells are deleted."""
    try:
        import matplotlib  # optional (pip install matplotlib): the report says when it is missing

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # optional, as above
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
    for old in set(out_dir.glob("*.png")) - set(paths):  # a task whose cells were taken out of the grid
        old.unlink()
    return paths
