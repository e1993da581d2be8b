"""``d5rl bench`` and ``d5rl report``: wired into :mod:`d5rl.cli` with :func:`add_bench_parser`
and :func:`add_report_parser`."""

from __future__ import annotations

import argparse
import fnmatch
import json
import sys

from d5rl.agents import AGENTS
from d5rl.errors import D5RLError
from d5rl.registry import TASK_ID_RE, base_task, get_spec, list_tasks, resolve
from d5rl.runner.bench import run_bench
from d5rl.runner.grid import DEFAULT_JOB, GridError, canonical_algo, expand_grid, parse_assignments, stale_reason
from d5rl.runner.report import ReportError, write_report
from d5rl.training.config import check_run
from d5rl.training.rundir import RunDir


def resolve_tasks(names: list[str]) -> list[str]:
    """Task ids; a family or prefix (``a1``, ``kitchen-standard``) stands for all its registered tasks
    except the ``-state`` twins of camera tasks (the benchmark's rows) and tasks whose dataset cannot be
    made yet (``DatasetSpec.unavailable``: an explicit id says why), a glob (``'kitchen-*-state-v0'``)
    for those it matches.  A prefix or glob takes a task on a dataset variant (``...-human-v0``) only when
    it names the variant: its dataset may not be on this machine."""

    def tasks_for(part: str) -> list[str]:
        words = set(part.replace("*", "-").split("-"))
        return [t for t in list_tasks() if not get_spec(t).variant or get_spec(t).variant in words]

    out: list[str] = []
    for name in names:
        for part in name.split(","):
            part = part.strip()
            if not part:
                continue
            if any(c in part for c in "*?["):
                matches = fnmatch.filter(tasks_for(part), part)
                if not matches:
                    raise D5RLError(f"no registered task matches {part!r}", "run `d5rl list` to see the task ids")
                out += matches
            elif TASK_ID_RE.match(part):
                out.append(get_spec(part).id)  # unknown ids raise with suggestions
            else:
                matches = [
                    t
                    for t in tasks_for(part)
                    if t.startswith(part + "-")
                    and (not base_task(t).endswith("-state-v0") or "state" in part)
                    and not (get_spec(t).dataset and get_spec(t).dataset.unavailable)
                ]
                if not matches:
                    raise D5RLError(
                        f"no registered task is or starts with {part!r}", "run `d5rl list` to see the task ids"
                    )
                out += matches
    return list(dict.fromkeys(out))


def _check_algos(algos: list[str], job: str) -> list[str]:
    names = [canonical_algo(a) for part in algos for a in part.split(",") if a.strip()]
    if job == DEFAULT_JOB:
        unknown = [a for a in names if a not in AGENTS]
        if unknown:
            raise GridError(f"unknown algorithms {unknown}", f"choose from {', '.join(AGENTS)}")
    return list(dict.fromkeys(names))


def _seeds(values: list[str]) -> list[int]:
    """``0 1 2``, ``0,1,2`` or ``0-2``: non-negative integers, ranges ascending."""
    out = []
    for v in values:
        for part in (p.strip() for p in v.split(",") if p.strip()):
            lo, sep, hi = part.partition("-")
            if not lo.isdecimal() or (sep and not hi.isdecimal()) or (sep and int(hi) < int(lo)):
                raise GridError(
                    f"--seeds: {part!r} is not a seed or an ascending range of seeds",
                    "pass non-negative integers (0 1 2) or a range (0-4)",
                )
            out += list(range(int(lo), int(hi or lo) + 1))
    return list(dict.fromkeys(out))


def _check_resources(args) -> None:
    for name, v, ok, want in (
        ("--workers", args.workers, args.workers is None or args.workers >= 0, ">= 0"),
        ("--max-attempts", args.max_attempts, args.max_attempts >= 1, ">= 1"),
        ("--cpus-per-cell", args.cpus_per_cell, args.cpus_per_cell > 0, "> 0"),
        ("--gpus-per-cell", args.gpus_per_cell, args.gpus_per_cell >= 0, ">= 0"),
        ("--nice", args.nice, 0 <= args.nice <= 19, "from 0 to 19"),
    ):
        if not ok:
            raise GridError(f"{name} must be {want}, got {v}", f"omit {name} for its default")


def cmd_bench(args) -> int:
    try:  # import the job first: a custom job's module may register its own tasks
        resolve(args.job)
    except (ImportError, AttributeError, ValueError) as e:
        raise GridError(f"cannot import the job {args.job!r} ({e})", "give --job as 'package.module:function'") from e
    tasks = resolve_tasks(args.tasks)
    algos = _check_algos(args.algos, args.job)
    seeds = _seeds(args.seeds)
    _check_resources(args)
    if args.job == DEFAULT_JOB:
        for seed in seeds:
            check_run(args.offline_steps, args.online_steps, seed)
    protocol = {}
    if args.eval_episodes is not None:
        protocol["eval_episodes"] = args.eval_episodes
        protocol["final_eval_episodes"] = args.eval_episodes
    if args.final_eval_episodes is not None:
        protocol["final_eval_episodes"] = args.final_eval_episodes
    if args.eval_interval is not None:
        protocol["eval_interval"] = args.eval_interval
    cells = expand_grid(
        tasks,
        algos,
        seeds,
        args.offline_steps,
        args.online_steps,
        overrides=parse_assignments(args.set),
        job=args.job,
        tuned=not args.no_tuned,
        protocol_overrides=protocol,
    )
    if args.dry_run:
        for c in cells:
            print(
                c.key,
                f"[{_cell_status(c, args.out)}]",
                f"offline {c.offline_steps}, online {c.online_steps}",
                _resolved_summary(c, args.job),
            )
        print(f"{len(cells)} cells")
        return 0
    print(
        f"{len(tasks)} tasks × {len(algos)} algorithms × {len(seeds)} seeds = {len(cells)} cells -> {args.out}",
        file=sys.stderr,
    )
    result = run_bench(
        cells,
        args.out,
        workers=args.workers,
        ray_address=args.ray,
        max_attempts=args.max_attempts,
        progress=not args.no_progress,
        nice=args.nice,
        cpus_per_cell=args.cpus_per_cell,
        gpus_per_cell=args.gpus_per_cell,
        prepare_data=not args.no_prepare_data,
    )
    print(result.summary(), file=sys.stderr)
    if not args.no_report:  # also after failures: the report lists the unfinished cells
        try:
            path = write_report(args.out)
            print(f"report: {path}", file=sys.stderr)
        except ReportError as e:
            print(f"no report: {e}", file=sys.stderr)
    return 1 if result.failed else 0


def _cell_status(cell, run_dir) -> str:
    """ "done", "stale: <why>" (finished on data the task no longer has: it would run again) or "to run"."""
    cdir = cell.directory(run_dir)
    if not RunDir(cdir).is_done():
        return "to run"
    why = stale_reason(cell, cdir)
    return "done" if why is None else f"stale: {why}"


def _resolved_summary(cell, job: str) -> str:
    """What d5rl's trainer will run a cell with (the settings file under the user's values)."""
    if job != DEFAULT_JOB:
        return f"{cell.overrides} {cell.protocol}"
    r = cell.spec()
    return json.dumps({"agent": r.agent.to_dict(), "train": r.train.to_dict()}, sort_keys=True)


def cmd_report(args) -> int:
    path = write_report(
        args.run_dir,
        args.out,
        reps=args.reps,
        seed=args.seed,
        plots=not args.no_plots,
        videos=args.video_tasks or args.videos,
    )
    print(path.read_text() if args.print else f"wrote {path}")
    return 0


def add_bench_parser(subparsers) -> argparse.ArgumentParser:
    q = subparsers.add_parser(
        "bench",
        help="train a grid of tasks × algorithms × seeds (resumable; local processes or Ray)",
        description="Run every (task, algorithm, seed) cell of a grid. Finished cells are skipped, so "
        "rerunning the same command resumes a killed sweep; a failing cell is retried once.",
    )
    q.add_argument(
        "--tasks",
        nargs="+",
        required=True,
        help="task ids, or prefixes standing for all their tasks (a1, kitchen-standard)",
    )
    q.add_argument("--algos", nargs="+", required=True, help=" ".join(AGENTS))
    q.add_argument("--seeds", nargs="+", default=["0", "1", "2"], help="seeds (list, or a range like 0-4)")
    q.add_argument("--offline-steps", type=int, default=500_000, help="offline gradient steps (paper: 500k)")
    q.add_argument(
        "--online-steps",
        type=int,
        default=0,
        help="online fine-tuning steps after the offline phase (paper Table 2: 500k)",
    )
    q.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="agent or training-loop setting for every cell (beats d5rl/configs/settings.json); repeatable",
    )
    q.add_argument("--eval-episodes", type=int, help="evaluation episodes (default: the task family's protocol)")
    q.add_argument(
        "--final-eval-episodes",
        type=int,
        help="episodes of the evaluation at the end (default: --eval-episodes, else the family's protocol)",
    )
    q.add_argument("--eval-interval", type=int, help="steps between evaluations (default: the family's protocol)")
    q.add_argument("--no-tuned", action="store_true", help="use the agents' defaults, not d5rl/configs/settings.json")
    q.add_argument("--out", required=True, help="run directory (reuse it to resume)")
    q.add_argument("--workers", type=int, help="local worker processes (default: all cores; 0 = in this process)")
    q.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run on the Ray cluster at ADDRESS ('auto': the one `ray start` runs here; "
        "'local': start a private instance)",
    )
    q.add_argument("--cpus-per-cell", type=float, default=1.0, help="Ray: CPUs reserved per cell")
    q.add_argument("--gpus-per-cell", type=float, default=0.0, help="Ray: GPUs reserved per cell (fractions share)")
    q.add_argument("--max-attempts", type=int, default=2, help="attempts per cell and invocation (default 2)")
    q.add_argument("--nice", type=int, default=0, help="raise the workers' niceness by this much")
    q.add_argument(
        "--job",
        default="d5rl.runner.jobs:train_job",
        help="'module:function' run per cell as f(cell, cell_dir) (default: d5rl's trainer)",
    )
    q.add_argument(
        "--no-prepare-data",
        action="store_true",
        help="do not generate missing datasets before the cells start (each cell then loads its own)",
    )
    q.add_argument("--dry-run", action="store_true", help="list the cells and their settings, run nothing")
    q.add_argument("--no-report", action="store_true", help="do not write RUN_DIR/report after the sweep")
    q.set_defaults(func=cmd_bench)
    return q


def add_report_parser(subparsers) -> argparse.ArgumentParser:
    q = subparsers.add_parser("report", help="tables (paper layout), IQM with bootstrap CIs and curves of a run")
    q.add_argument("run_dir", help="the --out directory of `d5rl bench`")
    q.add_argument("--out", help="where to write (default: RUN_DIR/report)")
    q.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (default 2000)")
    q.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    q.add_argument("--no-plots", action="store_true", help="skip the learning-curve PNGs")
    q.add_argument(
        "--videos",
        action="store_true",
        help="render one rollout GIF per task from its best cell's checkpoint (needs JAX and GL)",
    )
    q.add_argument(
        "--video-tasks",
        nargs="+",
        metavar="TASK",
        help="as --videos, for these tasks only (the others' GIFs stay as they are)",
    )
    q.add_argument("--print", action="store_true", help="print report.md")
    q.set_defaults(func=cmd_report)
    return q
